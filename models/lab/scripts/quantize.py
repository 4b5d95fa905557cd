#!/usr/bin/env python3
"""ONNX Runtime static int8 quantisation of a Telextiles encoder.

Called by `telextiles-lab quantize` (which writes the calibration frames and
checks the result); not meant to be run by hand:

    quantize.py IN.onnx CALIB.npy OUT.onnx

CALIB.npy holds preprocessed DIGIT frames, float32 [N, 3, S, S], exactly as
the daemon feeds the model. The model is pre-processed (shape inference and
graph optimisation, as ONNX Runtime recommends), then quantised in QDQ
format: weights int8 per output channel, activations uint8 calibrated with
MinMax over the frames (the u8 x s8 form that x86 VNNI kernels run). The
`telextiles.*` metadata is kept; `telextiles.quantization` records how.
Requirements: onnxruntime==1.31.1, onnx, numpy (installed by .ci/setup into
/opt/telextiles/pyenv).
"""
import os
import sys
import tempfile

import numpy as np
import onnx
from onnxruntime.quantization import (
    CalibrationDataReader,
    CalibrationMethod,
    QuantFormat,
    QuantType,
    quantize_static,
)
from onnxruntime.quantization.shape_inference import quant_pre_process


class Frames(CalibrationDataReader):
    def __init__(self, frames, name, batch=16):
        self.frames = frames
        self.name = name
        self.batch = batch
        self.pos = 0

    def get_next(self):
        if self.pos >= len(self.frames):
            return None
        x = self.frames[self.pos : self.pos + self.batch]
        self.pos += self.batch
        return {self.name: x}

    def rewind(self):
        self.pos = 0


def main():
    if len(sys.argv) != 4:
        sys.exit("usage: quantize.py IN.onnx CALIB.npy OUT.onnx")
    src, calib, out = sys.argv[1:]
    frames = np.load(calib)
    if frames.dtype != np.float32 or frames.ndim != 4 or frames.shape[1] != 3:
        sys.exit(f"{calib}: expected float32 [N, 3, S, S], got {frames.dtype} {frames.shape}")
    model = onnx.load(src)
    meta = {p.key: p.value for p in model.metadata_props}
    name = model.graph.input[0].name
    with tempfile.TemporaryDirectory() as tmp:
        pre = os.path.join(tmp, "pre.onnx")
        quant_pre_process(src, pre, skip_symbolic_shape=True)
        qpath = os.path.join(tmp, "q.onnx")
        quantize_static(
            pre,
            qpath,
            Frames(frames, name),
            quant_format=QuantFormat.QDQ,
            per_channel=True,
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
            calibrate_method=CalibrationMethod.MinMax,
        )
        q = onnx.load(qpath)
    del q.metadata_props[:]
    meta["telextiles.quantization"] = (
        f"int8 static QDQ (onnxruntime {__import__('onnxruntime').__version__}): "
        f"weights s8 per channel, activations u8 MinMax over {len(frames)} DIGIT frames"
    )
    for k, v in meta.items():
        e = q.metadata_props.add()
        e.key, e.value = k, v
    onnx.save(q, out)


if __name__ == "__main__":
    main()
