"""``radarcal quantise MODEL --images DIR -o MODEL.int8.onnx``: an int8 copy of a detector / number classifier,
calibrated on the user's frames, with its speed and its agreement with the float model (:mod:`radarcal.runtime.quantise`)."""

from __future__ import annotations

from pathlib import Path

import typer

from radarcal.cli.common import JsonOpt, emit

__all__ = ["quantise"]


def quantise(
    model: Path = typer.Argument(..., help="Float ONNX model (any --detector / --armour layout, or a --number classifier)."),
    images: Path = typer.Option(..., "--images", help="Calibration frames: a folder of images, or a replay folder (its images/). Crops for a classifier."),
    out: Path = typer.Option(..., "--out", "-o", help="The int8 ONNX file to write (give it to run --detector / --number)."),
    held_out: Path = typer.Option(None, "--held-out", help="Frames for the agreement check (default: the images not used to calibrate)."),
    frames: int = typer.Option(32, "--frames", min=1, max=1000, help="Calibration frames (evenly sampled from --images)."),
    activations: str = typer.Option("uint8", "--activations", help="uint8 (onnxruntime's fast int8 path, the default) or int8 (symmetric: fastest with --providers openvino)."),
    conf: float = typer.Option(0.25, "--conf", help="Score threshold of the box agreement check (detectors)."),
    as_json: JsonOpt = False,
) -> None:
    """Write an int8 (QDQ, per-channel) copy of MODEL; print its CPU time against the float model and how far its outputs moved on held-out frames."""
    from radarcal.io.outputs import check_outputs
    from radarcal.runtime.quantise import quantise_model

    check_outputs(None, [("int8 model", out)], inputs=[model])  # before any work: a failed command writes nothing
    r = quantise_model(model, out, images, held_out=held_out, activations=activations, max_frames=frames, conf=conf)

    def human(r: dict) -> None:
        a = r["agreement"]
        print(f"wrote {r['path']}: {r['quantised']} of {r['convs']} convolutions int8 (activations {r['activations']}), calibrated on {r['frames']} frames")
        print(f"  CPU per run (onnxruntime, 1 thread): float {r['ms_fp32']:.1f} ms, int8 {r['ms_int8']:.1f} ms ({r['ms_int8'] / r['ms_fp32']:.2f}x)")
        src = "the calibration frames (no others given)" if r["held_out_is_calibration"] else f"{r['held_out']} held-out frames"
        line = f"  agreement on {src}: output RMS difference {a['rms_diff']:.3g} (float output's frame-to-frame spread {a['rms_spread']:.3g})"
        if "top1" in a:
            line += f"; same class on {100 * a['top1']:.0f} % of crops, probabilities within {a['max_prob_diff']:.3f}"
        if a.get("boxes"):
            line += (f"; {a['boxes']} float boxes at conf {conf}: {100 * a['matched']:.0f} % found again (IoU median {a['iou_median']:.3f}, min {a['iou_min']:.3f}; "
                     f"score diff median {a['score_diff_median']:.3f}, max {a['score_diff_max']:.3f}), {a['extra']} extra")  # fmt: skip
        elif "boxes" in a:
            line += f"; the float model finds no box at conf {conf} on these frames"
        print(line)

    emit(r, as_json, human)
