"""Forward-backward smoothing of a replay (issue 16): accuracy, memory and time, from `zennav replay --smooth`'s
own code path (zennav.replay.run_replay(smoothing=True), zennav.metrics.evaluate) with the ins's filter parameters
(deploy/ins.yaml), as the command runs them.

accuracy  simulated car and multirotor (600 s, 200 Hz, exact truth; --seeds): GNSS withheld 30 s every 120 s and
          60 s every 180 s; RMS and max over all windows of the per-window maximum horizontal error, forward vs
          smoothed; and the horizontal RMS with full GNSS.
rtk       rtklibexplorer (500 s drive, scored against the withheld RTK fixes): 30 s every 90 s and 60 s every 120 s,
          without and with the non-holonomic constraint.
long      a 30 min simulated car drive at 200 Hz: wall time of the forward pass without and with the recorder and of
          the smoothing (CPU time: the machine may be shared), the recorder's stored bytes and the peak memory growth.
interval  the cost against cov_interval_s (300 s car at 200 Hz): epochs, stored MB, backward time, accuracy.

    .venv/bin/python benchmarks/smoother.py [--only accuracy,rtk,long,interval] [--seeds 0]
"""
from __future__ import annotations

import argparse
import resource
import time

import numpy as np

from zennav.datasets.registry import load_dataset
from zennav.metrics import evaluate
from zennav.params import load_filter_params, nav_config
from zennav.replay import ReplayResult, run_replay
from zennav.sim.scenarios import make_dataset


def _ins_filter(ds):
    ds.config = nav_config(ds.config, load_filter_params(None))  # as zennav replay: the ins's filter
    return ds


def _smoothed(res: ReplayResult) -> ReplayResult:
    assert res.smoothed is not None  # run_replay(smoothing=True)
    return res.smoothed


def _peaks(m: dict) -> list[float]:
    return [o["max_horizontal_m"] for o in m["outages"]]


def _rms(x) -> float:
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x * x)))


def _pct(fwd: float, smo: float) -> str:
    return f"{100.0 * (fwd - smo) / fwd:5.0f}%"


def accuracy(seeds: list[int]) -> None:
    print("simulated drives, 600 s at 200 Hz, seeds", seeds)
    print(f"{'drive':>11}{'GNSS':>16}{'windows':>8}{'fwd RMS m':>11}{'smo RMS m':>11}{'lower':>7}"
          f"{'fwd max m':>11}{'smo max m':>11}")
    for kind in ("car", "multirotor"):
        for label, every in (("30 s every 120", (120.0, 30.0, 90.0)), ("60 s every 180", (180.0, 60.0, 120.0)),
                             ("full", None)):
            fwd, smo, h_fwd, h_smo = [], [], [], []
            for seed in seeds:
                ds = _ins_filter(load_dataset(f"sim:{kind}", seed=seed))
                res = run_replay(ds, outage_every=every, smoothing=True)
                mf, ms = evaluate(ds, res), evaluate(ds, _smoothed(res))
                fwd += _peaks(mf)
                smo += _peaks(ms)
                h_fwd.append(mf["horizontal_rms_m"])
                h_smo.append(ms["horizontal_rms_m"])
            if every is None:
                f, s = _rms(h_fwd), _rms(h_smo)
                print(f"{kind:>11}{'full (hRMS)':>16}{'-':>8}{f:>11.3f}{s:>11.3f}{_pct(f, s):>7}")
            else:
                f, s = _rms(fwd), _rms(smo)
                print(f"{kind:>11}{label:>16}{len(fwd):>8}{f:>11.2f}{s:>11.2f}{_pct(f, s):>7}{max(fwd):>11.2f}"
                      f"{max(smo):>11.2f}", flush=True)


def rtk() -> None:
    print("rtklibexplorer, scored against the withheld RTK fixes")
    print(f"{'GNSS withheld':>16}{'NHC':>5}{'windows':>8}{'fwd RMS m':>11}{'smo RMS m':>11}{'lower':>7}"
          f"{'fwd max m':>11}{'smo max m':>11}{'fwd hRMS':>10}{'smo hRMS':>10}{'bridged':>8}")
    for label, every in (("30 s every 90", (90.0, 30.0, 60.0)), ("60 s every 120", (120.0, 60.0, 60.0))):
        for nhc in (False, True):
            ds = _ins_filter(load_dataset("rtklibexplorer"))
            ds.config = ds.config.with_(nhc=nhc)
            res = run_replay(ds, outage_every=every, smoothing=True)
            mf, ms = evaluate(ds, res), evaluate(ds, _smoothed(res))
            f, s = _rms(_peaks(mf)), _rms(_peaks(ms))
            print(f"{label:>16}{'on' if nhc else 'off':>5}{len(mf['outages']):>8}{f:>11.2f}{s:>11.2f}{_pct(f, s):>7}"
                  f"{max(_peaks(mf)):>11.2f}{max(_peaks(ms)):>11.2f}{mf['horizontal_rms_m']:>10.2f}"
                  f"{ms['horizontal_rms_m']:>10.2f}{_smoothed(res).status['smoother']['bridged_resets']:>8}",
                  flush=True)


def _maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _cpu_replay(ds, every, smoothing: bool):
    """run_replay and the CPU time it took [s] (the machine is shared: CPU time, not wall time, compares)."""
    cpu0 = time.process_time()
    res = run_replay(ds, outage_every=every, smoothing=smoothing)
    return res, time.process_time() - cpu0


def long() -> None:
    t0 = time.perf_counter()
    ds = _ins_filter(make_dataset("car", duration_s=1800.0, imu_rate_hz=200.0, seed=0))
    print(f"30 min simulated car at 200 Hz ({len(ds.imu.t_ns)} IMU samples, made in {time.perf_counter() - t0:.0f} s), "
          "GNSS withheld 60 s every 300 s; CPU time of this process (the machine is shared), the lesser of two "
          "alternated runs")
    every = (300.0, 60.0, 240.0)
    cpu: dict[str, list[float]] = {"plain": [], "recorded": [], "smoothing": [], "backward": []}
    growth = peak = 0.0
    for rep in range(2):
        plain, cpu_plain = _cpu_replay(ds, every, False)
        cpu["plain"].append(cpu_plain)
        del plain
        rss0 = _maxrss_mb()
        res, cpu_all = _cpu_replay(ds, every, True)
        if rep == 0:
            peak = _maxrss_mb()
            growth = peak - rss0
        st = _smoothed(res).status["smoother"]
        cpu["recorded"].append(cpu_all - st["cpu_s"])
        cpu["smoothing"].append(st["cpu_s"])
        cpu["backward"].append(st["backward_wall_s"])
    fwd, rec, smo, back = (min(cpu[k]) for k in ("plain", "recorded", "smoothing", "backward"))
    mf, ms = evaluate(ds, res), evaluate(ds, _smoothed(res))
    n = res.smoothing.s.shape[1]
    print(f"forward pass without recorder  {fwd:7.2f} s CPU")
    print(f"forward pass with recorder     {rec:7.2f} s CPU ({100 * (rec / fwd - 1):+.0f}%)")
    print(f"smoothing (backward + rows)    {smo:7.2f} s CPU = {smo / fwd:.2f} x the forward pass (backward wall "
          f"{back:.2f} s; {st['epochs']} epochs, {st['rows_smoothed']} rows)")
    per_epoch = st["stored_bytes"] / st["epochs"]
    print(f"recorder's stored arrays       {st['stored_bytes'] / 2**20:7.1f} MiB  ({per_epoch:.0f} B per epoch = "
          f"{per_epoch / (8 * n * n):.2f} n x n float64 matrices, n = {n})")
    print(f"peak memory growth of a replay with smoothing over one without: {growth:.0f} MiB (recorder, smoothed "
          f"solution and temporaries; process peak {peak:.0f} MiB with the 30 min dataset)")
    print(f"outage peaks RMS fwd {_rms(_peaks(mf)):.2f} m, smoothed {_rms(_peaks(ms)):.2f} m; horizontal RMS fwd "
          f"{mf['horizontal_rms_m']:.3f} m, smoothed {ms['horizontal_rms_m']:.3f} m")


def interval() -> None:
    print("cost against cov_interval_s: 300 s simulated car at 200 Hz, GNSS withheld 30 s every 120 s (CPU time)")
    print(f"{'cov_interval_s':>15}{'epochs':>8}{'stored MiB':>12}{'fwd+rec s':>10}{'smooth s':>10}{'fwd RMS m':>11}"
          f"{'smo RMS m':>11}")
    for dt in (0.01, 0.02, 0.05, 0.1, 0.2):
        ds = _ins_filter(make_dataset("car", duration_s=300.0, imu_rate_hz=200.0, seed=0))
        ds.config = ds.config.with_(cov_interval_s=dt)
        res, cpu_all = _cpu_replay(ds, (120.0, 30.0, 90.0), True)
        st = _smoothed(res).status["smoother"]
        f, s = _rms(_peaks(evaluate(ds, res))), _rms(_peaks(evaluate(ds, _smoothed(res))))
        print(f"{dt:>15.2f}{st['epochs']:>8}{st['stored_bytes'] / 2**20:>12.1f}{cpu_all - st['cpu_s']:>10.2f}"
              f"{st['cpu_s']:>10.2f}{f:>11.2f}{s:>11.2f}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", default="accuracy,rtk,long,interval")
    ap.add_argument("--seeds", default="0")
    a = ap.parse_args()
    parts = a.only.split(",")
    seeds = [int(s) for s in a.seeds.split(",")]
    for name in parts:
        {"accuracy": lambda: accuracy(seeds), "rtk": rtk, "long": long, "interval": interval}[name]()
        print()


if __name__ == "__main__":
    main()
