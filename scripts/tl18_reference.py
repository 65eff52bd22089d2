#!/usr/bin/env python3
"""MagNav's TL18 in numpy/scipy: the yardstick `calibrate --method tl` is timed against.

Usage: python3 scripts/tl18_reference.py FLIGHT.csv   (pip install numpy scipy)
Design matrix as host/src/estimate/tl (MagNav's create_TL_A, per-sample dB, Bt_scale
50,000 nT), 4-pole Butterworth 0.1-0.9 Hz filtfilt, 2 s trimmed, ridge lambda 0.001 by lstsq.
"""
import sys
import numpy as np
from scipy.signal import butter, sosfiltfilt

with open(sys.argv[1]) as f:  # '# key: value' lines, then the header row
    skip = next(i for i, l in enumerate(f) if not l.startswith("#"))
    f.seek(0)
    names = [f.readline() for _ in range(skip + 1)][-1].strip().split(",")
cols = ["t", "mag", "flux_x", "flux_y", "flux_z"]
d = dict(zip(cols, np.loadtxt(sys.argv[1], delimiter=",", skiprows=skip + 1,
                              usecols=[names.index(c) for c in cols], unpack=True)))
fs = 1.0 / np.median(np.diff(d["t"]))
B = np.column_stack([d["flux_x"], d["flux_y"], d["flux_z"]])
bt = np.linalg.norm(B, axis=1)
hat, dB = B / bt[:, None], np.gradient(B, axis=0)  # central, one-sided at the ends
ind = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
A = np.column_stack([hat] + [hat[:, p] * B[:, q] / 50000.0 for p, q in ind]
                    + [hat[:, p] * dB[:, q] / 50000.0 for p in range(3) for q in range(3)])
sos = butter(4, [0.1, 0.9], btype="band", fs=fs, output="sos")
trim = int(round(2 * fs))
Af = sosfiltfilt(sos, A, axis=0)[trim:-trim]
yf = sosfiltfilt(sos, d["mag"])[trim:-trim]
lam = 0.001  # magcomp's default ridge, as extra rows sqrt(lam)*I
c = np.linalg.lstsq(np.vstack([Af, np.sqrt(lam) * np.eye(18)]),
                    np.concatenate([yf, np.zeros(18)]), rcond=None)[0]
print("\n".join(f"{v:.6f}" for v in c))
