"""Int8 copies of a detector or classifier ONNX model (``radarcal quantise``): onnxruntime's static quantisation in
the QDQ format, per-channel int8 weights, activations calibrated (min / max) on the user's own frames, letterboxed
exactly as :class:`radarcal.runtime.detector.OnnxDetector` feeds the model. The backbone and neck (every node on a
path into a convolution) become int8; the decode after the last convolutions (DFL, anchors, box scaling, sigmoid
scores, NMS of end-to-end graphs) stays float, so box coordinates keep sub-pixel resolution.

``activations="uint8"`` (asymmetric, the onnxruntime CPU kernels' fast path, VNNI / AMX int8) is the default;
``"int8"`` (symmetric) is what OpenVINO runs fastest. The returned report measures what the copy costs and how far
its outputs move on frames that were not used to calibrate it."""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from radarcal.errors import InputError
from radarcal.io.onnx_files import load_onnx, save_onnx
from radarcal.io.replay import IMAGE_SUFFIXES

__all__ = ["quantise_model", "model_tensors", "output_agreement", "detection_agreement", "feeds_a_conv"]


def _images_of(src) -> list:
    """Image paths (a folder, a replay folder with images/, or a list of files) or arrays, as given."""
    if isinstance(src, (str, os.PathLike)):
        p = Path(src)
        if p.is_dir() and (p / "images").is_dir():
            p = p / "images"
        if not p.is_dir():
            raise InputError(p, "calibration images: expected a folder of images (or a replay folder with images/)")
        files = sorted(f for f in p.iterdir() if f.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise InputError(p, f"no images ({', '.join(IMAGE_SUFFIXES)}) in the folder")
        return files
    return list(src)


def model_tensors(model_path, images, kind: str | None = None) -> tuple[np.ndarray, str]:
    """The tensors the runtime feeds ``model_path`` for ``images`` (paths or BGR arrays), n x C x H x W float32, and
    the model kind: ``detector`` (letterboxed like ``OnnxDetector``) or ``classifier`` (N x classes output: resized
    like ``NumberClassifier``)."""
    import cv2

    from radarcal.io.images import read_image
    from radarcal.runtime.detector import OnnxModel, to_tensor

    m = OnnxModel(model_path, channels=(1, 3))
    if kind is None:
        kind = "classifier" if len(m.outputs) == 1 and len(m.outputs[0][1]) == 2 else "detector"
    imgs = [read_image(i) if isinstance(i, (str, os.PathLike)) else i for i in images]
    if kind == "classifier":
        h, w = m.input_size
        return to_tensor([cv2.resize(im, (w, h), interpolation=cv2.INTER_AREA) for im in imgs], m.channels), kind
    from radarcal.runtime.detector import OnnxDetector

    det = OnnxDetector(model_path)
    return np.stack([det.prepare(im).tensor for im in imgs]), kind


def feeds_a_conv(model) -> tuple[list[str], int]:
    """(names of the nodes that lie on no path into a Conv, number of Conv nodes) of an onnx ``model`` whose nodes
    all have names: what follows the last convolutions is the decode."""
    prod = {o: n for n in model.graph.node for o in n.output}
    seen: set[str] = set()
    stack = [n for n in model.graph.node if n.op_type == "Conv"]
    n_conv = len(stack)
    while stack:
        n = stack.pop()
        if n.name in seen:
            continue
        seen.add(n.name)
        stack.extend(prod[i] for i in n.input if i in prod)
    return [n.name for n in model.graph.node if n.name not in seen], n_conv


def _session(path, threads: int = 1):
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.log_severity_level = 3
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])


def _run_all(sess, x: np.ndarray) -> list[np.ndarray]:
    """Outputs for each frame of ``x`` run one at a time (fixed batch-1 models too), stacked per output."""
    name = sess.get_inputs()[0].name
    per = [sess.run(None, {name: x[i : i + 1]}) for i in range(len(x))]
    return [np.concatenate([p[k] for p in per]) for k in range(len(per[0]))]


def output_agreement(ref: list[np.ndarray], test: list[np.ndarray], kind: str) -> dict:
    """How far ``test`` outputs move from ``ref`` (both: per output, frames stacked on axis 0). ``rel_diff``: RMS of
    the difference over the RMS of the reference's frame-to-frame variation (what the input changes; 0 = identical,
    1 = as large as the signal), both RMS values (``rms_diff``, ``rms_spread``); classifiers add ``top1`` (share of frames with the same class)."""
    num = den = 0.0
    for r, t in zip(ref, test):
        r, t = np.asarray(r, np.float64), np.asarray(t, np.float64)
        num += float(np.sum((t - r) ** 2))
        den += float(np.sum((r - r.mean(axis=0, keepdims=True)) ** 2))
    size = sum(np.asarray(r).size for r in ref)
    out = {"rel_diff": float(np.sqrt(num / den)) if den > 0 else float("inf" if num > 0 else 0.0), "rms_diff": float(np.sqrt(num / size)), "rms_spread": float(np.sqrt(den / size))}
    if kind == "classifier":
        out["top1"] = float(np.mean(ref[0].argmax(1) == test[0].argmax(1)))
        out["max_prob_diff"] = float(np.abs(ref[0] - test[0]).max())
    return out


def detection_agreement(ref_model, test_model, images, conf: float = 0.25, iou_match: float = 0.5) -> dict:
    """Boxes of ``test_model`` against those of ``ref_model`` on ``images`` (decoded by ``OnnxDetector`` at ``conf``):
    ``boxes`` (reference boxes), ``matched`` (share with a same-label test box of IoU >= ``iou_match``), median and
    minimum IoU of the matches, median and max |score difference|, ``extra`` (unmatched test boxes)."""
    from radarcal.io.images import read_image
    from radarcal.runtime.detector import OnnxDetector, _iou

    a, b = OnnxDetector(ref_model, conf_thres=conf, threads=1), OnnxDetector(test_model, conf_thres=conf, threads=1)
    ious, dscore, n_ref, n_test, n_match = [], [], 0, 0, 0
    for im in images:
        im = read_image(im) if isinstance(im, (str, os.PathLike)) else im
        ra, rb = a(im), b(im)
        n_ref, n_test = n_ref + len(ra), n_test + len(rb)
        used: set[int] = set()
        for d in ra:
            cand = [(i, e) for i, e in enumerate(rb) if e.label == d.label and i not in used]
            if not cand:
                continue
            ov = _iou(d.xyxy, np.array([e.xyxy for _, e in cand]))
            k = int(np.argmax(ov))
            if ov[k] >= iou_match:
                used.add(cand[k][0])
                n_match += 1
                ious.append(float(ov[k]))
                dscore.append(abs(cand[k][1].score - d.score))
    return {"boxes": n_ref, "matched": n_match / n_ref if n_ref else float("nan"), "iou_median": float(np.median(ious)) if ious else float("nan"),
            "iou_min": float(np.min(ious)) if ious else float("nan"), "score_diff_median": float(np.median(dscore)) if dscore else float("nan"),
            "score_diff_max": float(np.max(dscore)) if dscore else float("nan"), "extra": n_test - n_match}  # fmt: skip


def _cpu_ms(sess, x: np.ndarray, runs: int = 5) -> float:
    name = sess.get_inputs()[0].name
    sess.run(None, {name: x[:1]})
    c0 = time.process_time()
    for i in range(runs):
        sess.run(None, {name: x[i % len(x) : i % len(x) + 1]})
    return (time.process_time() - c0) / runs * 1e3


def quantise_model(src, dst, images, held_out=None, activations: str = "uint8", max_frames: int = 32, per_channel: bool = True, conf: float = 0.25) -> dict:
    """Write an int8 QDQ copy of ``src`` to ``dst``, calibrated on up to ``max_frames`` of ``images`` (a folder, a
    replay folder, or a list of paths / BGR arrays; evenly sampled). ``held_out``: frames for the agreement check
    (default: the images not used to calibrate, else the calibration frames themselves, flagged). Returns
    {kind, convs, quantised, frames, held_out, ms_fp32, ms_int8 (CPU per run, onnxruntime, one thread),
    agreement: :func:`output_agreement` and, detectors, :func:`detection_agreement` at ``conf``}. Nothing is
    written when the quantisation fails."""
    try:
        import onnx  # noqa: F401 - checked here: radarcal.io.onnx_files reads and writes the models with it
        from onnxruntime.quantization import CalibrationDataReader, CalibrationMethod, QuantFormat, QuantType, quantize_static
    except ImportError as e:
        raise InputError("radarcal quantise", f"needs the onnx package ({e.name} missing: pip install onnx, or radarcal[speed])") from None
    if activations not in ("uint8", "int8"):
        raise InputError("--activations", f"expected uint8 or int8, got {activations!r}")
    src, dst = Path(src), Path(dst)
    files = _images_of(images)
    pick = np.unique(np.linspace(0, len(files) - 1, min(max_frames, len(files))).round().astype(int))
    calib = [files[i] for i in pick]
    rest = [f for i, f in enumerate(files) if i not in set(pick.tolist())]
    check = _images_of(held_out) if held_out is not None else (rest[:16] or calib[:8])
    x_cal, kind = model_tensors(src, calib)
    x_chk, _ = model_tensors(src, check, kind)

    model = load_onnx(src)
    for i, n in enumerate(model.graph.node):
        if not n.name:
            n.name = f"{n.op_type}_{i}"
    exclude, n_conv = feeds_a_conv(model)
    if n_conv == 0:
        raise InputError(src, "no Conv node: nothing to quantise")
    input_name = model.graph.input[0].name

    class _Frames(CalibrationDataReader):
        def __init__(self):
            self.it = iter([{input_name: x_cal[i : i + 1]} for i in range(len(x_cal))])

        def get_next(self):
            return next(self.it, None)

    with tempfile.TemporaryDirectory() as tmp:
        named = Path(tmp) / "named.onnx"
        save_onnx(model, named)
        out_tmp = Path(tmp) / "int8.onnx"
        act = QuantType.QUInt8 if activations == "uint8" else QuantType.QInt8
        try:
            quantize_static(str(named), str(out_tmp), _Frames(), quant_format=QuantFormat.QDQ, per_channel=per_channel, activation_type=act,
                            weight_type=QuantType.QInt8, nodes_to_exclude=exclude, calibrate_method=CalibrationMethod.MinMax,
                            extra_options={"ActivationSymmetric": activations == "int8"})  # fmt: skip
        except Exception as e:  # noqa: BLE001 - onnxruntime.quantization raises many types
            msg = str(e).strip().splitlines()[0][:160] if str(e).strip() else e.__class__.__name__
            raise InputError(src, f"cannot quantise ({msg})") from None
        qmodel = load_onnx(out_tmp)
        del qmodel.metadata_props[:]
        for p in model.metadata_props:  # names, imgsz, stride, author: the runtime reads the layout from them
            qmodel.metadata_props.add().CopyFrom(p)
        entry = qmodel.metadata_props.add()
        entry.key, entry.value = "radarcal_quantised", f"int8 QDQ per-channel, activations {activations}, {len(calib)} calibration frames"
        fs = _session(named)
        save_onnx(qmodel, out_tmp)
        qs = _session(out_tmp)
        agreement = output_agreement(_run_all(fs, x_chk), _run_all(qs, x_chk), kind)
        if kind == "detector":
            agreement.update(detection_agreement(named, out_tmp, check, conf))
        ms_fp32, ms_int8 = _cpu_ms(fs, x_chk), _cpu_ms(qs, x_chk)
        n_q = _quantised_convs(qmodel)
        dst.parent.mkdir(parents=True, exist_ok=True)
        tmp_dst = dst.with_name(dst.name + ".part")
        save_onnx(qmodel, tmp_dst)
        os.replace(tmp_dst, dst)
    return {"kind": kind, "convs": n_conv, "quantised": n_q, "frames": len(calib), "held_out": len(check), "held_out_is_calibration": not rest and held_out is None,
            "ms_fp32": ms_fp32, "ms_int8": ms_int8, "agreement": agreement, "activations": activations, "path": str(dst)}  # fmt: skip


def _quantised_convs(qmodel) -> int:
    """Conv nodes of a QDQ model whose weight comes through a DequantizeLinear."""
    deq = {o for n in qmodel.graph.node if n.op_type == "DequantizeLinear" for o in n.output}
    return sum(1 for n in qmodel.graph.node if n.op_type == "Conv" and len(n.input) > 1 and n.input[1] in deq)
