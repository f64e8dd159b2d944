#!/usr/bin/env python3
"""Independent reference values for tests/it/catalogue.rs.

Each catalogue model is written here again in plain Python (math module, IEEE double), straight from
../shared/models.md, and evaluated at a few points. The Rust test compares lobe's result with these numbers, so
a transcription error in a .brdf file or a semantic error in lobe shows up as a mismatch. Run it to regenerate
the table printed into catalogue.rs: python3 tests/data/catalogue_values.py
"""
import math

def clamp01(x): return min(max(x, 0.0), 1.0)

def phong(NL, NV, NH, VR, VH, n): return VR ** n
def blinn(NL, NV, NH, VR, VH, n): return NH ** n
def schlick(NL, NV, NH, VR, VH, n): c = NH; return c / (n - n * c + c)
def schlick_vr(NL, NV, NH, VR, VH, n): c = VR; return c / (n - n * c + c)
def gaussian(NL, NV, NH, VR, VH, n): return math.exp(-n * math.acos(NH) ** 2 / 2)
def ward(NL, NV, NH, VR, VH, n, m=0.3):
    return 1 / math.sqrt(NL * NV) / (4 * math.pi * m * m) * math.exp((NH * NH - 1) / (m * m * NH * NH))
def beckmann(NL, NV, NH, VR, VH, n, m=0.3):
    return 1 / (m * m * NH ** 4) * math.exp((NH * NH - 1) / (m * m * NH * NH))
def cook_torrance(NL, NV, NH, VR, VH, n, m=0.3, F0=0.04):
    D = beckmann(NL, NV, NH, VR, VH, n, m)
    G = min(1, 2 * NH * NV / VH, 2 * NH * NL / VH)
    F = F0 + (1 - F0) * (1 - VH) ** 5
    return F * D * G / (math.pi * NL * NV)
def modified_schlick(NL, NV, NH, VR, VH, n): c = NH; return 2 * c / (1.25 * (n - n * c + 1.25 * c) ** 2)
def modified_schlick_vr(NL, NV, NH, VR, VH, n): c = VR; return 2 * c / (1.25 * (n - n * c + 1.25 * c) ** 2)
def dsh(NL, NV, NH, VR, VH, n):
    c = NH
    return c / (n - n * c + c) + (2 * (c + 0.1) ** 8 / (1.25 * (1.25 * n - 1.25 * n * c + 1.25 * c ** 8) ** 2 + 1.5) - 0.25)
def scos(NL, NV, NH, VR, VH, n):
    c = NH
    return (n / 2 * (c - 1) + 1) ** 2 if c >= (n - 2) / n else 0.0
def scos2(NL, NV, NH, VR, VH, n):
    c = NH
    return ((-1.1 / (-n + n * c - 2 * c)) * n * (c - 1) + 1) ** 2 if c >= n / (n + 20) else 0.0
def fst(NL, NV, NH, VR, VH, n, a=16):
    c = NH
    return (n / a * (c - 1) + 1) ** a if c >= 1 - a / n else 0.0
def quadratic(NL, NV, NH, VR, VH, n): c = NH; return 0.786 * n * c * c + (1 - 0.786 * n) * c
def kutlog(NL, NV, NH, VR, VH, n, k=1, Q=0.5):
    x = math.acos(NH)
    arg = math.acos(Q ** (1 / k)) / math.acos(Q ** (1 / n)) * x
    return math.cos(arg) ** k if arg < math.pi / 2 else 0.0

MODELS = [
    ("phong", phong, {}), ("blinn", blinn, {}), ("schlick", schlick, {}), ("schlick_vr", schlick_vr, {}),
    ("gaussian", gaussian, {}), ("ward", ward, {"m": 0.3}), ("beckmann", beckmann, {"m": 0.3}),
    ("cook_torrance", cook_torrance, {"m": 0.3, "F0": 0.04}), ("modified_schlick", modified_schlick, {}),
    ("modified_schlick_vr", modified_schlick_vr, {}), ("dsh", dsh, {}), ("scos", scos, {}), ("scos2", scos2, {}),
    ("fst", fst, {"a": 16}), ("quadratic", quadratic, {}), ("kutlog", kutlog, {"k": 1, "Q": 0.5}),
]
# (NL, NV, NH, VR, VH) points and exponents: peak, near peak, shoulder, far.
POINTS = [(0.7, 0.6, 0.999, 0.998, 0.8), (0.5, 0.9, 0.95, 0.9, 0.7), (0.9, 0.3, 0.8, 0.6, 0.95)]
NS = [1, 10, 50, 200]

for name, f, extra in MODELS:
    print(f'    ("{name}", &[')
    for n in NS:
        for p in POINTS:
            v = max(f(*p, n, **extra), 0.0)
            print(f"        ({n}.0, [{p[0]}, {p[1]}, {p[2]}, {p[3]}, {p[4]}], {v!r}),")
    print("    ]),")
