#!/usr/bin/env python3
"""The gait phase term a trainer computes, built with NumPy: one [cos, sin] (or [sin, cos]) pair per
policy step, for a period in ticks, with the counter advanced before the observation (as a trainer
that increments its phase counter at the top of the step) or after it. An independent check of the
runtime's `phase` term: the test compares the observations a run recorded with this.

    phase_trace.py --period 40 --steps 200 [--advance-first] [--sin-first]   → JSON [[a, b], ...]
"""
import argparse
import json

import numpy as np


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--period", type=int, required=True)
    p.add_argument("--steps", type=int, required=True)
    p.add_argument("--advance-first", action="store_true")
    p.add_argument("--sin-first", action="store_true")
    a = p.parse_args()
    counter = np.arange(a.steps, dtype=np.int64)
    if a.advance_first:
        counter = counter + 1
    phase = 2.0 * np.pi * (counter % a.period) / a.period
    pair = np.stack([np.sin(phase), np.cos(phase)] if a.sin_first else [np.cos(phase), np.sin(phase)], axis=1)
    print(json.dumps(pair.astype(np.float32).astype(float).tolist()))


if __name__ == "__main__":
    main()
