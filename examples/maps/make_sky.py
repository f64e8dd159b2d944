#!/usr/bin/env python3
"""Writes sky.hdr: a 128×64 latitude-longitude Radiance map (flat RGBE) of a procedural sky — a blue gradient
above the horizon, a small warm sun, a brown ground — for examples/scenes/environment.toml. Deterministic, no
dependencies: `python3 examples/maps/make_sky.py` regenerates the committed file byte for byte."""
import math, os

W, H = 128, 64
SUN_U, SUN_V, SUN_R = 0.62, 0.28, 0.035  # the sun's centre (u, v) and angular radius in v units


def rgbe(r, g, b):
    m = max(r, g, b)
    if m < 1e-32:
        return bytes(4)
    e = math.floor(math.log2(m)) + 1
    s = 256.0 / 2.0 ** e
    return bytes([min(255, int(r * s)), min(255, int(g * s)), min(255, int(b * s)), e + 128])


def pixel(x, y):
    u, v = (x + 0.5) / W, (y + 0.5) / H
    if v < 0.5:
        t = v / 0.5  # 0 at the zenith, 1 at the horizon
        sky = (0.25 + 0.55 * t, 0.45 + 0.45 * t, 1.0)
        du = min(abs(u - SUN_U), 1 - abs(u - SUN_U)) * 2  # u spans 2π, v spans π
        if math.hypot(du, v - SUN_V) < SUN_R:
            return (60.0, 52.0, 40.0)
        return sky
    return (0.25, 0.18, 0.12)


out = bytearray(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n" % (H, W))
for y in range(H):
    for x in range(W):
        out += rgbe(*pixel(x, y))
with open(os.path.join(os.path.dirname(os.path.abspath(__file__)), "sky.hdr"), "wb") as f:
    f.write(out)
