"""Robot detection: YOLO-family ONNX models through onnxruntime (layouts in :mod:`radarcal.runtime.yolo_layouts`),
or precomputed boxes from a JSON-lines file (read by :mod:`radarcal.io.detections_file`).

Input convention of every YOLO export: one N x 3 x H x W float image input (RGB, 0..1) after a letterbox (aspect
kept, grey 114 padding centred). Class names come from ``--names`` (YOLO ``data.yaml``, a text file one per line,
a JSON/YAML list or ``{id: name}`` mapping) or the model metadata ``names`` (YOLOv5 and ultralytics write
``{0: 'red_1', ...}``; both read in :mod:`radarcal.io.detector_files` / :mod:`radarcal.io.onnx_files`). Optional second and third stages (armour on robot crops, number on armour crops) are in
:mod:`radarcal.runtime.stages`.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from radarcal.errors import InputError
from radarcal.io.detector_files import class_names_from
from radarcal.io.onnx_files import check_onnx_header, parse_meta_value
from radarcal.runtime.yolo_layouts import Layout, UnknownLayout, decode_batch, decode_v5_rows, detect_layout, nms, read_anchor_config

__all__ = ["Detection", "Prepared", "letterbox", "tile_grid", "plan_rois", "decode_yolov5", "nms", "OnnxDetector", "OnnxModel", "OpenVinoSession", "DetectionsFile", "resolve_providers"]


@dataclass
class Detection:
    """One robot in image pixels. ``dead``: its armour is grey (tracked, never sent as a target); ``armour_label`` /
    ``number_label``: what the armour and number stages said (None without them)."""

    xyxy: np.ndarray  # (4,) image pixels
    label: str
    score: float
    class_id: int = -1
    dead: bool = False
    armour_label: str | None = None
    number_label: str | None = None
    armour_xyxy: np.ndarray | None = None  # (4,) image pixels

    def to_dict(self) -> dict:
        d = {"xyxy": [round(float(v), 2) for v in self.xyxy], "label": self.label, "score": round(float(self.score), 4)}
        if self.dead:
            d["dead"] = True
        if self.armour_label is not None:
            d["armour"] = self.armour_label
        if self.number_label is not None:
            d["number"] = self.number_label
        return d


def letterbox(img: np.ndarray, size: int | tuple[int, int] = 640, color: int = 114, scaleup: bool = True, out: np.ndarray | None = None) -> tuple[np.ndarray, float, tuple[float, float]]:
    """Resize keeping the aspect ratio and pad to ``size`` (h, w). Returns (image, scale, (pad_x, pad_y)):
    a letterboxed pixel ``p`` maps back to ``(p - pad) / scale`` in the original image. ``scaleup=False`` never
    enlarges (a small crop stays at its native resolution, padded). ``out``: a (h, w, C) uint8 buffer to write into
    (no new allocation; its padding is rewritten only where the content does not cover it)."""
    import cv2

    th, tw = (size, size) if isinstance(size, int) else size
    h, w = img.shape[:2]
    r = min(th / h, tw / w)
    if not scaleup:
        r = min(r, 1.0)
    nw, nh = max(int(round(w * r)), 1), max(int(round(h * r)), 1)
    dw, dh = (tw - nw) / 2.0, (th - nh) / 2.0
    top, bottom = int(round(dh - 0.1)), int(round(dh + 0.1))
    left, right = int(round(dw - 0.1)), int(round(dw + 0.1))
    channels = img.shape[2] if img.ndim == 3 else 1
    if out is not None and out.shape == (th, tw) + img.shape[2:] and out.dtype == img.dtype and img.ndim in (2, 3):
        out[:top], out[top + nh :], out[top : top + nh, :left], out[top : top + nh, left + nw :] = color, color, color, color
        inner = out[top : top + nh, left : left + nw]
        if (nw, nh) != (w, h):
            if left == 0 and right == 0:  # full-width rows: a contiguous block cv2 writes in place
                cv2.resize(img, (nw, nh), dst=inner, interpolation=cv2.INTER_LINEAR)
            else:
                inner[...] = cv2.resize(img, (nw, nh), interpolation=cv2.INTER_LINEAR).reshape(inner.shape)
        else:
            inner[...] = img.reshape(inner.shape)
        return out, r, (float(left), float(top))
    if (nw, nh) != (w, h):
        img = cv2.resize(img, (nw, nh), interpolation=cv2.INTER_LINEAR)
    value = (color,) * channels
    out = cv2.copyMakeBorder(img, top, bottom, left, right, cv2.BORDER_CONSTANT, value=value)
    return out, r, (float(left), float(top))


def decode_yolov5(pred: np.ndarray, conf_thres: float = 0.25, iou_thres: float = 0.45, max_det: int = 300) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, 5+C) or (1, N, 5+C) raw YOLOv5 rows -> (boxes xyxy (K,4), scores (K,), class ids (K,)) after the
    confidence filter and class-aware NMS (boxes of different classes never suppress each other)."""
    pred = np.asarray(pred, dtype=np.float32)
    if pred.ndim == 3:
        pred = pred[0]
    if pred.ndim != 2 or pred.shape[1] < 6:
        raise ValueError(f"expected a (N, 5+C) YOLOv5 output, got {pred.shape}")
    return decode_v5_rows(pred, conf_thres, iou_thres, max_det)


# --- onnxruntime sessions ----------------------------------------------------------------------------------------------
PROVIDERS = {"cpu": "CPUExecutionProvider", "cuda": "CUDAExecutionProvider", "tensorrt": "TensorrtExecutionProvider", "trt": "TensorrtExecutionProvider",
             "openvino": "OpenVINOExecutionProvider", "dml": "DmlExecutionProvider", "coreml": "CoreMLExecutionProvider"}  # fmt: skip
# ``--providers`` names served by the ``openvino`` package itself when onnxruntime has no OpenVINO provider: the
# precision OpenVINO runs the float layers in (None: its default, bf16 on CPUs with AMX / AVX512-BF16, else f32)
OPENVINO_NAMES = {"openvino": None, "openvino-bf16": "bf16", "openvino-f32": "f32"}
_NOTES_SHOWN: set[str] = set()


def _provider_items(spec: str | list[str] | None) -> list[str]:
    return [s.strip() for s in (spec.split(",") if isinstance(spec, str) else (spec or ["cpu"])) if s.strip()]


def resolve_providers(spec: str | list[str] | None) -> tuple[list[str], list[str]]:
    """(providers onnxruntime has, in the order asked, CPU last; the ones asked for but missing) from
    ``"tensorrt,cuda,cpu"``-style text. Unknown names raise InputError."""
    import onnxruntime as ort

    want = []
    for s in _provider_items(spec):
        p = PROVIDERS.get(s.lower(), "OpenVINOExecutionProvider" if s.lower() in OPENVINO_NAMES else (s if s.endswith("ExecutionProvider") else None))
        if p is None:
            raise InputError("--providers", f"unknown provider {s!r} (cpu, cuda, tensorrt, openvino, openvino-bf16, openvino-f32, dml, coreml)")
        if p not in want:
            want.append(p)
    have = set(ort.get_available_providers())
    use = [p for p in want if p in have and p != "CPUExecutionProvider"] + ["CPUExecutionProvider"]
    return use, [p for p in want if p not in have]


def _note(msg: str) -> None:
    if msg not in _NOTES_SHOWN:
        _NOTES_SHOWN.add(msg)
        sys.stderr.write(msg + "\n")


class OpenVinoSession:
    """The part of an onnxruntime ``InferenceSession`` radarcal uses (``run``, ``get_inputs`` / ``get_outputs`` /
    ``get_modelmeta``), over the same ONNX file compiled by OpenVINO for the CPU (``pip install openvino``): on Intel
    CPUs with AMX / AVX512-BF16 its default runs the float layers in bf16, and an int8 QDQ model
    (``radarcal quantise``) on the VNNI / AMX int8 kernels. ``ort_session``: an onnxruntime session of the file,
    kept for the graph's names, shapes and metadata only.

    ``threads`` > 0: that many threads per inference and ``cpu_count // threads`` streams, so that that many calls
    from different threads (``--detect-workers``) run at the same time; 0: one stream on all cores (lowest latency
    of one call). Threads are not pinned to cores (the station PC runs other work too). One infer request per
    calling thread."""

    def __init__(self, path: str | os.PathLike, ort_session, threads: int = 0, precision: str | None = None):
        import openvino as ov

        self._ort = ort_session
        cfg: dict = {"ENABLE_CPU_PINNING": False}
        if threads:
            streams = max((os.cpu_count() or 1) // int(threads), 1)
            cfg.update({"NUM_STREAMS": streams, "INFERENCE_NUM_THREADS": streams * int(threads)})
        else:
            cfg["PERFORMANCE_HINT"] = "LATENCY"
        if precision:
            cfg["INFERENCE_PRECISION_HINT"] = precision
        self.compiled = ov.Core().compile_model(str(path), "CPU", cfg)
        hint = self.compiled.get_property("INFERENCE_PRECISION_HINT")
        self.precision = hint.get_type_name() if hasattr(hint, "get_type_name") else str(hint)  # bf16 / f32 / f16
        self.version = str(getattr(ov, "__version__", "")).split("-")[0]
        self._ports = {o.get_any_name(): o for o in self.compiled.outputs}
        for o in self.compiled.outputs:
            for n in o.get_names():
                self._ports.setdefault(n, o)
        self._local = threading.local()

    def run(self, output_names, feed: dict) -> list[np.ndarray]:
        req = getattr(self._local, "req", None)
        if req is None:
            req = self._local.req = self.compiled.create_infer_request()
        res = req.infer({k: np.ascontiguousarray(v) for k, v in feed.items()})
        return [np.array(res[self._ports[n]], copy=True) for n in output_names]  # the request's buffers are reused by its next call

    def get_inputs(self):
        return self._ort.get_inputs()

    def get_outputs(self):
        return self._ort.get_outputs()

    def get_modelmeta(self):
        return self._ort.get_modelmeta()

    def get_providers(self) -> list[str]:
        return [f"OpenVINO-CPU-{self.precision}"]


class OnnxModel:
    """An onnxruntime session on one image-input model, with the checks every stage needs: the file is ONNX, the
    input is N x C x H x W (C = ``channels``), the providers asked for exist (else a one-line note and CPU).

    ``threads``: intra-op threads (0 = onnxruntime's default, one per core); ``spin``: let them busy-wait (slightly
    lower latency on a dedicated machine, CPU stolen from everything else on a shared one)."""

    def __init__(self, path: str | os.PathLike, what: str = "ONNX model", threads: int = 0, spin: bool = False, providers=None,
                 channels: tuple[int, ...] = (3,), default_size: int = 640):  # fmt: skip
        import onnxruntime as ort

        self.path = Path(path)
        if not self.path.is_file():
            raise InputError(self.path, f"{what} not found")
        so = ort.SessionOptions()
        if threads:
            so.intra_op_num_threads = int(threads)
        so.inter_op_num_threads = 1
        so.log_severity_level = 3
        if not spin:  # idle worker threads sleep instead of spinning: no CPU stolen from the rest of the loop / machine
            so.add_session_config_entry("session.intra_op.allow_spinning", "0")
        items = _provider_items(providers)
        ov_item = next((i for i in items if i.lower() in OPENVINO_NAMES), None)
        native_ov = False
        if ov_item is not None and "OpenVINOExecutionProvider" not in ort.get_available_providers():
            items = [i for i in items if i.lower() not in OPENVINO_NAMES] or ["cpu"]
            try:
                import openvino  # noqa: F401

                native_ov = True
            except ImportError:
                _note(f"note: {ov_item} needs the openvino package (pip install openvino, or radarcal[speed]); running {self.path.name} on CPU (onnxruntime)")
        if native_ov:  # onnxruntime only reads the graph's names, shapes and metadata: no optimisation, one thread
            so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
            so.intra_op_num_threads = 1
        use, missing = resolve_providers(items)
        if missing:
            _note(f"note: onnxruntime {ort.__version__} has no {', '.join(missing)} (install onnxruntime-gpu with matching CUDA/TensorRT); "
                  f"running {self.path.name} on {', '.join(p.replace('ExecutionProvider', '') for p in use)}")  # fmt: skip
        opts = []
        for p in use:
            if p == "TensorrtExecutionProvider":  # engines are slow to build: cache them next to the model
                opts.append({"trt_engine_cache_enable": "True", "trt_engine_cache_path": str(self.path.parent), "trt_fp16_enable": "True"})
            else:
                opts.append({})
        try:
            check_onnx_header(self.path)
            self.session = ort.InferenceSession(str(self.path), so, providers=use, provider_options=opts)
        except Exception as e:  # noqa: BLE001 - onnxruntime raises its own exception types
            msg = str(e).strip().splitlines()[0][:120] if str(e).strip() else e.__class__.__name__
            raise InputError(self.path, f"cannot load {what} ({msg})") from None
        got = self.session.get_providers()
        lost = [p for p in use if p not in got]
        if lost:
            _note(f"note: {', '.join(lost)} failed to start for {self.path.name} (CUDA/TensorRT libraries?); running on {', '.join(got)}")
        if native_ov:
            try:
                self.session = OpenVinoSession(self.path, self.session, threads, OPENVINO_NAMES[ov_item.lower()])
                got = self.session.get_providers()
            except Exception as e:  # noqa: BLE001 - OpenVINO raises RuntimeError subclasses of its own
                msg = str(e).strip().splitlines()[0][:120] if str(e).strip() else e.__class__.__name__
                _note(f"note: OpenVINO cannot compile {self.path.name} ({msg}); running it on CPU (onnxruntime)")
                so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
                so.intra_op_num_threads = int(threads) if threads else 0
                self.session = ort.InferenceSession(str(self.path), so, providers=use, provider_options=opts)
                got = self.session.get_providers()
        self.providers = got
        self.meta = {k: parse_meta_value(v) for k, v in self.session.get_modelmeta().custom_metadata_map.items()}
        inp = self.session.get_inputs()[0]
        self.input_name = inp.name
        shape = list(inp.shape)
        self.inputs = [(i.name, list(i.shape)) for i in self.session.get_inputs()]
        self.outputs = [(o.name, list(o.shape)) for o in self.session.get_outputs()]
        self.output_names = [o.name for o in self.session.get_outputs()]
        if len(shape) != 4:
            raise InputError(self.path, f"{what}: input {inp.name} has rank {len(shape)} ({'x'.join(map(str, shape))}); expected an N x C x H x W image")
        c = shape[1] if isinstance(shape[1], int) else channels[-1]
        if c not in channels:
            raise InputError(self.path, f"{what}: input {inp.name} has {c} channels ({'x'.join(map(str, shape))}); expected {' or '.join(map(str, channels))}")
        self.channels = int(c)
        imgsz = self.meta.get("imgsz")
        if isinstance(imgsz, int):
            imgsz = [imgsz, imgsz]
        dh = int(imgsz[0]) if isinstance(imgsz, (list, tuple)) and imgsz else default_size
        dw = int(imgsz[-1]) if isinstance(imgsz, (list, tuple)) and imgsz else default_size
        self.input_size = (int(shape[2]) if isinstance(shape[2], int) else dh, int(shape[3]) if isinstance(shape[3], int) else dw)
        self.batch = int(shape[0]) if isinstance(shape[0], int) and shape[0] > 0 else None  # None: any batch
        self.dtype = np.float16 if "float16" in inp.type else np.float32

    def run_batch(self, x: np.ndarray, parallel: int = 1) -> list[tuple[int, list[np.ndarray]]]:
        """Run ``x`` (n x C x H x W float32, 0..1) in as few calls as the input's batch size allows; the outputs of
        each call (a fixed batch is padded with zeros, its extra rows ignored by the caller). ``parallel`` > 1: the
        calls of a fixed-batch model run at the same time in that many threads (onnxruntime releases the GIL; with one
        intra-op thread per call this is how two frames use two cores)."""
        n = len(x)
        step = self.batch or max(n, 1)
        chunks = []
        for s in range(0, max(n, 1), step):
            chunk = x[s : s + step]
            if self.batch and len(chunk) < self.batch:
                chunk = np.concatenate([chunk, np.zeros((self.batch - len(chunk),) + chunk.shape[1:], chunk.dtype)])
            chunks.append((min(step, n - s), chunk.astype(self.dtype, copy=False)))
        run = lambda c: self.session.run(self.output_names, {self.input_name: c})  # noqa: E731
        if parallel > 1 and len(chunks) > 1:
            return [(k, o) for (k, _), o in zip(chunks, self._pool(parallel).map(run, [c for _, c in chunks]))]
        return [(k, run(c)) for k, c in chunks]

    _pools: dict = {}

    @classmethod
    def _pool(cls, n: int):
        """One shared thread pool per size (threads live as long as the process; idle ones sleep)."""
        from concurrent.futures import ThreadPoolExecutor

        if n not in cls._pools:
            cls._pools[n] = ThreadPoolExecutor(n, thread_name_prefix="radarcal-onnx")
        return cls._pools[n]


def _planes(im: np.ndarray, out: np.ndarray, channels: int) -> None:
    """One BGR (or grey) uint8 image -> ``out`` (C, H, W) float32 in 0..1: RGB planes, or grey for C = 1."""
    import cv2

    if channels == 1:
        g = im if im.ndim == 2 else cv2.cvtColor(im, cv2.COLOR_BGR2GRAY)
        np.multiply(g, 1.0 / 255.0, out=out[0], casting="unsafe")
    elif im.ndim == 2:  # a mono camera's frame into a colour model: the same plane three times
        np.multiply(im, 1.0 / 255.0, out=out[0], casting="unsafe")
        out[1:] = out[0]
    else:
        for c in range(3):  # RGB planes from BGR
            np.multiply(im[:, :, 2 - c], 1.0 / 255.0, out=out[c], casting="unsafe")


def to_tensor(images: list[np.ndarray], channels: int = 3) -> np.ndarray:
    """BGR uint8 images of one size -> n x C x H x W float32 in 0..1 (RGB, or grey for C = 1). One scaled copy per
    channel plane (6x faster than a transposed ``astype`` of the whole stack)."""
    h, w = images[0].shape[:2]
    x = np.empty((len(images), channels, h, w), np.float32)
    for i, im in enumerate(images):
        _planes(im, x[i], channels)
    return x


@dataclass
class Prepared:
    """One frame letterboxed for a detector (:meth:`OnnxDetector.prepare`): ``tensor`` (C, H, W) float32, the
    letterbox ``scale`` and ``pad`` (x, y), the frame's ``hw``, and the frame itself (``image``)."""

    image: np.ndarray
    tensor: np.ndarray
    scale: float
    pad: tuple[float, float]
    hw: tuple[int, int]


class OnnxDetector:
    """A YOLO-family ONNX detector: any layout of :mod:`radarcal.runtime.yolo_layouts`, detected from the graph or
    forced with ``layout``; ``detector(image) -> [Detection]``, ``detector([images]) -> [[Detection], ...]`` (one
    batched run when the model's batch dimension allows). ``last_timings_ms``: preprocess / infer / decode of the last
    call. ``names_source``: the file the names came from (named in a class-count error)."""

    def __init__(self, model_path: str | os.PathLike, class_names: list[str] | None = None, conf_thres: float = 0.25, iou_thres: float = 0.45,
                 threads: int = 0, spin: bool = False, layout: str | None = None, providers=None, anchors: dict | None = None,
                 names_source: str | os.PathLike | None = None, max_det: int = 300, what: str = "ONNX model", parallel: int = 1):  # fmt: skip
        self.model = OnnxModel(model_path, what, threads, spin, providers)
        self.parallel = max(int(parallel), 1)  # concurrent runs of a fixed-batch model over several images (run_batch)
        self._ahead: dict[int, Prepared] = {}
        self._ahead_lock = threading.Lock()
        self._local = threading.local()
        self.path = self.model.path
        self.session = self.model.session
        self.input_name = self.model.input_name
        self.input_size = self.model.input_size
        meta_names = class_names_from(self.model.meta.get("names"))
        nc_hint = len(class_names) if class_names else (len(meta_names) if meta_names else None)
        try:
            self.layout: Layout = detect_layout(self.model.inputs, self.model.outputs, self.model.meta, nc_hint, layout)
        except UnknownLayout as e:
            raise InputError(self.path, str(e)) from None
        if self.layout.name == "raw":
            self.layout.anchors, self.layout.strides, self.layout.sigmoid = read_anchor_config(anchors)
        names = list(class_names) if class_names else (meta_names or [])
        nc = self.layout.nc
        if names and nc is not None and len(names) != nc:
            src = names_source if class_names else self.path
            raise InputError(src, f"{len(names)} class names but {self.path.name} has {nc} classes ({self.layout.name} layout, output "
                                  f"{'x'.join(map(str, self.model.outputs[0][1]))})")  # fmt: skip
        if not names and nc is not None:
            names = [f"class_{i}" for i in range(nc)]
        self.class_names = names
        self.conf_thres = conf_thres
        self.iou_thres = iou_thres
        self.max_det = max_det
        self.last_timings_ms: dict[str, float] = {}

    def describe(self) -> str:
        lay = self.layout.name + (f"/{self.layout.variant}" if self.layout.variant else "")
        return f"{self.path.name}: {lay}, input {self.input_size[1]}x{self.input_size[0]}, {len(self.class_names)} classes, {'/'.join(p.replace('ExecutionProvider', '') for p in self.model.providers)}"

    def prepare(self, image: np.ndarray, scaleup: bool = True) -> Prepared:
        """Letterbox + float tensor of one BGR frame for this detector (a per-thread uint8 buffer, no padding copy)."""
        import cv2

        im = image
        if im.ndim == 3 and im.shape[2] != 3:  # BGRA / single-channel 3-D frames
            im = cv2.cvtColor(im, cv2.COLOR_BGRA2BGR) if im.shape[2] == 4 else im[:, :, 0]
        h, w = self.input_size
        key = (h, w) + im.shape[2:]
        buf = getattr(self._local, "buf", None)
        if buf is None or buf.shape != key:
            buf = self._local.buf = np.empty(key, np.uint8)
        lb, r, pad = letterbox(im, self.input_size, scaleup=scaleup, out=buf if im.dtype == np.uint8 else None)
        t = np.empty((self.model.channels, h, w), np.float32)
        _planes(lb, t, self.model.channels)
        return Prepared(image, t, r, pad, im.shape[:2])

    def prepare_ahead(self, image: np.ndarray) -> np.ndarray:
        """Letterbox ``image`` now (e.g. in the frame-prefetch thread) and keep it for the next :meth:`detect_batch`
        given the same image object, which then skips its preprocessing. Returns ``image``. At most 16 are kept."""
        p = self.prepare(image)
        with self._ahead_lock:  # the prefetch thread adds while the detect thread takes
            while len(self._ahead) >= 16:
                self._ahead.pop(next(iter(self._ahead)), None)
            self._ahead[id(image)] = p
        return image

    def _take(self, image) -> Prepared | None:
        if isinstance(image, Prepared):
            return image
        with self._ahead_lock:
            p = self._ahead.pop(id(image), None)
        return p if p is not None and p.image is image else None

    def preprocess(self, images: list) -> tuple[np.ndarray, list[tuple[float, tuple[float, float], tuple[int, int]]]]:
        """n frames (arrays, or :class:`Prepared`) -> n x C x H x W tensor and per frame (scale, pad, hw)."""
        h, w = self.input_size
        x = np.empty((len(images), self.model.channels, h, w), np.float32)
        geo = []
        for i, im in enumerate(images):
            p = self._take(im)
            if p is None:
                p = self.prepare(im)
            x[i] = p.tensor
            geo.append((p.scale, p.pad, p.hw))
        return x, geo

    def __call__(self, images):
        if isinstance(images, Prepared) or (isinstance(images, np.ndarray) and (images.ndim == 2 or (images.ndim == 3 and images.shape[2] in (1, 3, 4)))):
            return self.detect_batch([images])[0]
        return self.detect_batch(list(images))

    def _infer(self, x: np.ndarray, geo) -> tuple[list[list[Detection]], float, float]:
        t1 = time.perf_counter()
        runs = self.model.run_batch(x, self.parallel)
        t2 = time.perf_counter()
        decoded = []
        try:
            for n, outs in runs:
                decoded += decode_batch(outs, self.layout, n, self.input_size, self.conf_thres, self.iou_thres, self.max_det)
        except (ValueError, IndexError, KeyError) as e:
            raise InputError(self.path, f"output does not fit the {self.layout.name} layout ({e})") from None
        out = [self.postprocess(b, s, c, *g) for (b, s, c), g in zip(decoded, geo)]
        return out, (t2 - t1) * 1e3, (time.perf_counter() - t2) * 1e3

    def detect_batch(self, images: list) -> list[list[Detection]]:
        """Detections per frame (BGR arrays or :class:`Prepared`), in frame pixels."""
        t0 = time.perf_counter()
        if not images:
            self.last_timings_ms = {"preprocess": 0.0, "infer": 0.0, "decode": 0.0}
            return []
        x, geo = self.preprocess(images)
        pre = (time.perf_counter() - t0) * 1e3
        out, infer, dec = self._infer(x, geo)
        self.last_timings_ms = {"preprocess": pre, "infer": infer, "decode": dec}
        return out

    def detect_regions(self, image: np.ndarray, regions, full: list[Detection] | None = None, scaleup: bool = False, edge_px: float = 2.0) -> list[Detection]:
        """Detections inside regions of interest of one (large) frame, in frame pixels. Each region (K,4) xyxy frame
        pixels is cut out and letterboxed on its own, never enlarged unless ``scaleup`` (a far robot keeps its native
        pixels; a region larger than the input is shrunk to fit), all regions in one batched run (``parallel`` runs
        for a fixed-batch model). A box within ``edge_px`` of a region border that is not the frame's border is a
        robot cut by the window and dropped. Region boxes found twice (overlapping windows) go through class-aware
        NMS; with ``full`` (this frame's full-frame detections) the two are merged: a full-frame box overlapping a
        region box (IoU > ``iou_thres``, whatever its label: the window saw that robot at native resolution, and
        two labels on one robot would be two robots) gives way to it. ``last_timings_ms``: preprocess /
        infer / decode / merge and ``regions`` (count)."""
        t0 = time.perf_counter()
        H, W = image.shape[:2]
        wins = []
        for x0, y0, x1, y1 in np.asarray(regions, float).reshape(-1, 4):
            a, b = int(max(np.floor(x0), 0)), int(max(np.floor(y0), 0))
            c, d = int(min(np.ceil(x1), W)), int(min(np.ceil(y1), H))
            if c - a >= 2 and d - b >= 2:
                wins.append((a, b, c, d))
        found: list[Detection] = []
        pre = infer = dec = 0.0
        if wins:
            h, w = self.input_size
            x = np.empty((len(wins), self.model.channels, h, w), np.float32)
            geo = []
            for i, (a, b, c, d) in enumerate(wins):
                p = self.prepare(image[b:d, a:c], scaleup=scaleup)
                x[i] = p.tensor
                geo.append((p.scale, p.pad, p.hw))
            pre = (time.perf_counter() - t0) * 1e3
            per, infer, dec = self._infer(x, geo)
            for (a, b, c, d), dets in zip(wins, per):
                cw, ch = c - a, d - b
                for det in dets:
                    x1, y1, x2, y2 = det.xyxy
                    cut = (a > 0 and x1 <= edge_px) or (b > 0 and y1 <= edge_px) or (c < W and x2 >= cw - 1 - edge_px) or (d < H and y2 >= ch - 1 - edge_px)
                    if not cut:
                        det.xyxy = det.xyxy + np.array([a, b, a, b], np.float64)
                        found.append(det)
        t3 = time.perf_counter()
        if found:
            from radarcal.runtime.yolo_layouts import class_aware_nms

            boxes = np.array([d.xyxy for d in found], np.float32)
            keep = class_aware_nms(boxes, np.array([d.score for d in found], np.float32), np.array([d.class_id for d in found]), self.iou_thres, self.max_det)
            found = [found[i] for i in keep]
        out = found
        if full:
            rb = np.array([d.xyxy for d in found]).reshape(-1, 4)
            kept = [d for d in full if not len(rb) or not (_iou(d.xyxy, rb) > self.iou_thres).any()]
            out = sorted(kept + found, key=lambda d: -d.score)
        self.last_timings_ms = {"preprocess": pre, "infer": infer, "decode": dec, "merge": (time.perf_counter() - t3) * 1e3, "regions": float(len(wins))}
        return out

    def postprocess(self, boxes, scores, cls, r: float, pad: tuple[float, float], hw: tuple[int, int]) -> list[Detection]:
        """Letterbox pixels -> image pixels (clipped to the image), labels from the class names."""
        boxes = (np.asarray(boxes, np.float32) - np.array([pad[0], pad[1], pad[0], pad[1]], np.float32)) / r
        boxes[:, [0, 2]] = boxes[:, [0, 2]].clip(0, hw[1] - 1)
        boxes[:, [1, 3]] = boxes[:, [1, 3]].clip(0, hw[0] - 1)
        out = []
        for b, s, c in zip(boxes, scores, cls):
            c = int(c)
            label = self.class_names[c] if 0 <= c < len(self.class_names) else f"class_{c}"
            out.append(Detection(b.astype(np.float64), label, float(s), c))
        return out


def _iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """IoU of one xyxy box with (K,4) boxes."""
    iw = np.clip(np.minimum(box[2], boxes[:, 2]) - np.maximum(box[0], boxes[:, 0]), 0, None)
    ih = np.clip(np.minimum(box[3], boxes[:, 3]) - np.maximum(box[1], boxes[:, 1]), 0, None)
    inter = iw * ih
    union = (box[2] - box[0]) * (box[3] - box[1]) + (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1]) - inter
    return inter / np.maximum(union, 1e-12)


def tile_grid(hw: tuple[int, int], tile_hw: int | tuple[int, int] = 640, overlap: int = 64, align: int = 32) -> np.ndarray:
    """(K,4) xyxy windows of ``tile_hw`` (h, w) covering a frame of ``hw`` (h, w) pixels, neighbours overlapping by at
    least ``overlap`` pixels (more than a far robot is wide, so each one lies whole in some window). Window origins
    are multiples of ``align`` (the network's largest stride: every tile sees the same grid phase) except the last
    one of a row or column, which ends at the frame's edge."""
    H, W = hw
    th, tw = (tile_hw, tile_hw) if isinstance(tile_hw, int) else tile_hw

    def starts(n_px: int, t: int) -> np.ndarray:
        if n_px <= t:
            return np.array([0])
        k = max(int(np.ceil((n_px - t) / max(t - overlap - align, 1))) + 1, 2)  # floor to align loses < align of overlap
        step = (n_px - t) / (k - 1)
        s = (np.floor(np.arange(k - 1) * step / align) * align).astype(int)
        return np.append(s, n_px - t)

    xs, ys = starts(W, tw), starts(H, th)
    gx, gy = np.meshgrid(xs, ys)
    x0, y0 = gx.ravel(), gy.ravel()
    return np.column_stack([x0, y0, np.minimum(x0 + tw, W), np.minimum(y0 + th, H)]).astype(float)


def plan_rois(points_uv, hw: tuple[int, int], tile_hw: int | tuple[int, int] = 640, max_rois: int = 4, margin: float = 48.0) -> np.ndarray:
    """Detector windows (K,4) xyxy of ``tile_hw`` around image points ``points_uv`` (N,2), e.g. far tracks projected
    into the frame, in priority order (first = most wanted): a point already ``margin`` pixels inside a chosen
    window is covered by it; at most ``max_rois`` windows, each shifted to lie inside the frame."""
    H, W = hw
    th, tw = (tile_hw, tile_hw) if isinstance(tile_hw, int) else tile_hw
    tw, th = min(tw, W), min(th, H)
    wins: list[tuple[float, float, float, float]] = []
    for u, v in np.asarray(points_uv, float).reshape(-1, 2):
        if not (np.isfinite(u) and np.isfinite(v)) or not (0 <= u < W and 0 <= v < H):
            continue
        if any(a + margin <= u <= c - margin and b + margin <= v <= d - margin for a, b, c, d in wins):
            continue
        if len(wins) >= max_rois:
            break
        a = float(np.clip(np.round(u - tw / 2), 0, W - tw))
        b = float(np.clip(np.round(v - th / 2), 0, H - th))
        wins.append((a, b, a + tw, b + th))
    return np.array(wins, float).reshape(-1, 4)


@dataclass
class DetectionsFile:
    """Precomputed detections: one JSON line per frame ``{"t", "frame"?, "boxes": [{"xyxy", "label", "score", "dead"?}]}``.

    Lookup by frame name when given, else by the nearest time within ``tol`` seconds."""

    times: np.ndarray
    boxes: list[list[Detection]]
    by_frame: dict[str, int] = field(default_factory=dict)
    tol: float = 0.02

    @classmethod
    def read(cls, path: str | os.PathLike, tol: float = 0.02) -> "DetectionsFile":
        """The detections of a file (:func:`radarcal.io.detections_file.read_detections_file`), sorted by time."""
        from radarcal.io.detections_file import read_detections_file

        lines = read_detections_file(path)
        boxes = [[Detection(b["xyxy"], b["label"], b["score"], dead=b["dead"], armour_label=b["armour"], number_label=b["number"]) for b in ln.boxes]
                 for ln in lines]  # fmt: skip
        by_frame = {ln.frame: i for i, ln in enumerate(lines) if ln.frame is not None}
        times = [ln.t for ln in lines]
        order = np.argsort(times, kind="stable")
        remap = {int(o): k for k, o in enumerate(order)}
        return cls(np.asarray(times, float)[order], [boxes[o] for o in order], {k: remap[v] for k, v in by_frame.items()}, tol)

    def lookup(self, t: float, frame: str | None = None) -> list[Detection]:
        if frame is not None and frame in self.by_frame:
            return self.boxes[self.by_frame[frame]]
        if not len(self.times):
            return []
        i = int(np.searchsorted(self.times, t))
        cand = [j for j in (i - 1, i) if 0 <= j < len(self.times)]
        j = min(cand, key=lambda k: abs(self.times[k] - t))
        return self.boxes[j] if abs(self.times[j] - t) <= self.tol else []
