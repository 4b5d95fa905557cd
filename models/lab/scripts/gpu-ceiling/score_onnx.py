"""Scores an encoder that follows the Telextiles contract (ONNX, e.g.
models/encoder.onnx) on the presses of the GPU ceiling study, exactly as
ceiling.py scores its CNN: per press, the mean of three hold frames'
normalised embeddings, cosine 1-NN against the index's frames.

usage: score_onnx.py <dir of dump_presses output> <model.onnx> [name]
Needs numpy and onnxruntime (.ci/setup's /opt/telextiles/pyenv has both)."""
import json, sys
import numpy as np
import onnxruntime as ort

MEAN = np.array([0.37932363, 0.4131034, 0.38336082], np.float32)
STD = np.array([0.11476628, 0.08604312, 0.16590593], np.float32)
D, path = sys.argv[1], sys.argv[2]
so = ort.SessionOptions()
so.intra_op_num_threads = 2
sess = ort.InferenceSession(path, so)
meta = sess.get_modelmeta().custom_metadata_map
crop, size = int(meta["telextiles.crop"]), int(meta["telextiles.input_size"])
subtract = meta.get("telextiles.background") == "subtract"


def load(name):
    rows = [l.split() for l in open(f"{D}/{name}.meta.txt")]
    n = len(rows)
    fr = np.memmap(f"{D}/{name}.frames.u8", dtype=np.uint8, mode="r", shape=(n, 6, 240, 240, 3))
    rf = np.memmap(f"{D}/{name}.ref.u16", dtype=np.uint16, mode="r", shape=(n, 240, 240, 3))
    return fr, rf, np.array([int(r[0][1:]) - 1 for r in rows])


def contract(img):
    """The daemon's preprocessing of the 240-px centre square: centre crop,
    resize (an integer factor here: block means, as the bilinear resize with
    half-pixel centres gives), normalise; planar [3, S, S]."""
    o = (240 - crop) // 2
    x = img[o:o + crop, o:o + crop].astype(np.float32)
    k = crop // size
    assert k * size == crop, "score_onnx.py handles integer resize factors only"
    x = x.reshape(size, k, size, k, 3).mean((1, 3))
    return ((x / 255.0 - MEAN) / STD).transpose(2, 0, 1)


def embed(name):
    fr, rf, lab = load(name)
    out = []
    for i in range(len(lab)):
        ref = contract(rf[i].astype(np.float32) / 64.0)
        x = np.stack([contract(fr[i, f]) - (ref if subtract else 0) for f in (3, 4, 5)])
        e = sess.run(None, {"frames": x.astype(np.float32)})[0]
        out.append(e / np.maximum(np.linalg.norm(e, axis=1, keepdims=True), 1e-12))
    return np.stack(out), lab


def top1(index, query):
    (I, il), (Q, ql) = index, query
    ie = I.reshape(-1, I.shape[-1])
    labels = np.repeat(il, I.shape[1])
    q = Q.mean(1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return float((labels[(q @ ie.T).argmax(1)] == ql).mean())


E = {}
res = {}
for idx, q in [("idx", "qa"), ("idx", "qb"), ("idx", "qh"), ("g2idx", "g2qa"), ("g2idx", "g2qh")]:
    for s in (idx, q):
        if s not in E:
            E[s] = embed(s)
    res[q] = round(100 * top1(E[idx], E[q]), 1)
print(json.dumps({"model": sys.argv[3] if len(sys.argv) > 3 else path, **res}))
