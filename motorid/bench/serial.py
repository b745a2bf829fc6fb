"""``motorid bench serial``: the host's frame reader throughput, and a long real-time run through a pty.

1. Frames decoded per second by :class:`hardware.protocol.FrameReader` on a stream of
   SAMPLE frames fed in 4 KiB reads (as pyserial hands them over), against the goal of
   200 000 frames/s (about 100x the fastest an Uno can send: 500 000 baud, 8N1,
   21 bytes per SAMPLE frame = 2 381 frames/s); the same reader fed one byte per
   call (the worst split) and on a stream with 10 % of frames corrupted, measured
   in the same run, for comparison.
2. A real-time run through the emulated Arduino on a pty (default 60 s at 1 kHz,
   500 000 baud): samples received, lost on the link, dropped by the device, bad frames.
"""
from __future__ import annotations

import argparse
import math
import time
from typing import Sequence

import numpy as np

from motorid.bench.flags import integer, real

__all__ = ["bench_serial"]

_GOAL = 200_000
_UNO_MAX = 500_000 / 10 / 21      # frames/s at 500 000 baud, 10 bits per byte, 21 bytes per frame


def _stream(n: int, rng: np.random.Generator, corrupt: float = 0.0) -> bytes:
    from hardware import protocol as P
    counts = np.cumsum(rng.integers(-40, 41, n))
    duty = rng.integers(-255, 256, n)
    frames = []
    for k in range(n):
        wire = P.encode_message(P.Sample(k, 1000 * k & 0xFFFFFFFF, int(counts[k]), int(duty[k]), 0), k & 0xFF)
        if corrupt and rng.random() < corrupt:
            bad = bytearray(wire)
            bad[int(rng.integers(0, len(wire) - 1))] ^= 1 << int(rng.integers(0, 8))
            wire = bytes(bad)
        frames.append(wire)
    return b"".join(frames)


def _decode_rate(data: bytes, chunk: int, repeats: int) -> tuple[float, int, int]:
    from hardware.protocol import FrameReader
    best = math.inf
    for _ in range(repeats):
        reader = FrameReader()
        n = 0
        t0 = time.perf_counter()
        for i in range(0, len(data), chunk):
            n += len(reader.feed(data[i:i + chunk]))
        dt = time.perf_counter() - t0
        best = min(best, dt)
    return n / best, n, reader.rx_errors


def bench_serial(argv: Sequence[str]) -> int:
    """Print the reader's frames/s against the goal and the pty run's losses; exit 1 if a goal is missed."""
    from hardware.fake_device import FakeDevice
    from hardware.serial_rig import SerialRig
    from motorsim import PRBS, Encoder, Experiment, Motor

    p = argparse.ArgumentParser(prog="motorid bench serial", description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=integer(), default=200_000, help="frames in the decoding test (default 200000)")
    p.add_argument("--repeats", type=integer(), default=3, help="timings of the decoding, best kept (default 3)")
    p.add_argument("--duration", type=real(positive=False), default=60.0,
                   help="length of the pty run in s (default 60; 0 skips)")
    p.add_argument("--rate", type=real(), default=1000.0, help="sample rate of the pty run in Hz (default 1000)")
    p.add_argument("--baud", type=integer(), default=500_000, help="line rate of the pty run in baud (default 500000)")
    args = p.parse_args(list(argv))
    rng = np.random.default_rng(0)
    ok = True

    data = _stream(args.frames, rng)
    rate, n, errors = _decode_rate(data, 4096, args.repeats)
    one = data[: 21 * min(args.frames, 20_000)]
    rate1, _, _ = _decode_rate(one, 1, 1)
    bad = _stream(min(args.frames, 100_000), rng, corrupt=0.1)
    rate_bad, n_bad, err_bad = _decode_rate(bad, 4096, args.repeats)
    print("frame reader (hardware.protocol.FrameReader), SAMPLE frames of 21 bytes")
    print(f"  4 KiB reads               {rate:12,.0f} frames/s   ({n} decoded, {errors} errors)")
    print(f"  1-byte reads              {rate1:12,.0f} frames/s   (worst split, same reader)")
    print(f"  4 KiB, 10 % corrupted     {rate_bad:12,.0f} frames/s   ({n_bad} good, {err_bad} rejected)")
    print(f"  goal                      {_GOAL:12,.0f} frames/s   ratio {rate / _GOAL:.2f}x")
    print(f"  Uno's fastest (500 kBd)   {_UNO_MAX:12,.0f} frames/s   ratio {rate / _UNO_MAX:.0f}x")
    ok &= rate >= _GOAL and errors == 0

    if args.duration > 0:
        dt = round(1e6 / args.rate) * 1e-6
        exp = Experiment(PRBS(200, -200, 10, 5), dt, args.duration)
        print(f"pty run: emulated Arduino in real time, {exp.n_samples} samples at {1 / dt:g} Hz, "
              f"{args.baud} baud, {args.duration:g} s")
        with FakeDevice(Motor(25.0, 3.0), Encoder(), speed=1.0, rng=np.random.default_rng(1)) as dev:
            cpu0, t0 = time.process_time(), time.perf_counter()
            with SerialRig(dev.port_name, args.baud) as rig:
                rec = rig.run(exp)
            wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
        m = rec.metadata
        lost = exp.n_samples - len(rec)
        print(f"  received                  {len(rec)} of {exp.n_samples}")
        print(f"  lost on the link          {m['host_link_frames_lost']}")
        print(f"  dropped by the device     {m['device_samples_dropped']}")
        print(f"  bad frames                {m['host_rx_errors']}")
        print(f"  wall time                 {wall:.2f} s   (host + device CPU {cpu:.2f} s, "
              f"{100 * cpu / wall:.0f} % of one core)")
        print(f"  drops                     {lost}   (goal 0)")
        ok &= lost == 0
    return 0 if ok else 1
