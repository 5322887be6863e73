"""A 2D granular column collapsing on a 22 degree rough slope, run until rest.

Usage::

    python examples/collapse_2d_slope.py [--n 2000] [--slope 22] [--solver clarabel]
        [--tol 1e-6] [--t-max 6.0] [--bed-length 2.5] [--out results] [--name NAME]

The column (R0 x H0 = 20 x 14 cm, 10 % polydispersity) stands on a rough bed of
glued grains, tilted by ``--slope`` degrees (a tilted gravity), and is released
at t = 0. Friction is mu = 0.9, the seed paper's 2D calibration (section 4.2:
2D runs need it to reproduce 3D ones, having no lateral walls); its Fig. 7 runs
2154 discs on a 22 degree slope. The run stops when the kinetic energy of the flowing
main mass falls below 1e-6 of the potential energy released (``--rest``), or at
``--t-max``; isolated grains that roll away (rolling dissipates nothing in this
model) are left out of that test and of the front.

On a 22 degree slope a 2D mass of discs does not come to rest: after the
acceleration and deceleration phases it keeps spreading in a slow propagation
phase (the seed paper, section 5.1.1 and Figs. 9c, 10d and 11g: "the simulated
mass does not stop", unlike the experiment, for want of lateral walls). A run
with the defaults therefore ends at ``--t-max`` with a NOT-at-rest verdict and
its front velocity in that phase; on a horizontal bed (``--slope 0``) the front
stops within about 0.6 s and the kinetic energy decays towards the rest test.
It writes, under ``--out`` (file names start with ``--name``, default
``collapse_2d_slope``):

- ``NAME_profiles.png``: free-surface mass profiles h(x) at the start, at an
  intermediate time (``--t-mid``) and at the end;
- ``NAME_front.png`` and ``NAME_front.csv``: the front position r_f(t) (the
  furthest grain still connected to the mass) and the main mass's kinetic
  energy against time;
- ``NAME.meta.json``: the command, the machine and the at-rest verdict.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

import cocd
from cocd.bench.report import write_meta
from cocd.builders import grain_groups
from cocd.measure import front_position, kinetic_energy, main_mass, mass_profile


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=2000)
    parser.add_argument("--slope", type=float, default=22.0)
    parser.add_argument("--mu", type=float, default=0.9)
    parser.add_argument("--solver", default="clarabel")
    parser.add_argument("--tol", type=float, default=1e-6)
    parser.add_argument("--dt", type=float, default=1e-3)
    parser.add_argument("--t-max", type=float, default=6.0)
    parser.add_argument("--t-mid", type=float, default=0.4)
    parser.add_argument("--bed-length", type=float, default=2.5)
    parser.add_argument("--rest", type=float, default=1e-6)
    parser.add_argument("--out", default="results")
    parser.add_argument("--name", default="collapse_2d_slope", help="prefix of the files written")
    args = parser.parse_args()

    scene = cocd.column_collapse(
        2,
        n_grains=args.n,
        slope_deg=args.slope,
        bed="rough",
        bed_length=args.bed_length,
        mu=args.mu,
    )
    column = np.zeros(scene.n_grains, dtype=bool)
    column[grain_groups(scene)["column"]] = True
    r0 = scene.positions[column, 0].max() + scene.radii[column].max()
    out = Path(args.out)
    out.mkdir(exist_ok=True)
    stepper = cocd.Stepper(scene, args.dt, solver=args.solver, tol=args.tol)

    # Profile bins two mean diameters wide: finer bins see single grains.
    x_bins = np.arange(0.0, args.bed_length + 1e-9, 4.0 * float(scene.radii[column].mean()))
    profiles = {0.0: mass_profile(scene, x_bins=x_bins, mask=column)}
    pe0 = _potential(scene, column)
    times, fronts = [0.0], [front_position(scene, mask=column)]
    eks = [kinetic_energy(scene)]
    start = time.perf_counter()
    released, ek = 0.0, float("inf")
    while scene.time < args.t_max:
        record = stepper.step()
        times.append(scene.time)
        fronts.append(front_position(scene, mask=column))
        released = max(released, pe0 - _potential(scene, column))
        # Isolated grains roll down the slope for ever (rolling dissipates nothing
        # in this model): rest is judged on the main connected mass only.
        ek = kinetic_energy(_subset(scene, main_mass(scene, mask=column)))
        eks.append(ek)
        if stepper.step_count % 50 == 0:
            print(
                f"t = {scene.time:.3f} s  front {fronts[-1]:.4f} m  Ek {ek:.3e}  "
                f"Nc {record.nc}  iter {record.iterations}  ccp {record.ccp_residual:.1e}  "
                f"({time.perf_counter() - start:.0f} s)",
                flush=True,
            )
        if stepper.step_count % 250 == 0:  # a failed long run keeps its front so far
            _write_front(out / f"{args.name}_front.csv", times, fronts, eks)
        if scene.time >= args.t_mid and len(profiles) == 1:
            profiles[round(scene.time, 3)] = mass_profile(scene, x_bins=x_bins, mask=column)
        if scene.time > 0.05 and released > 0 and ek < args.rest * released:
            break
    profiles[round(scene.time, 3)] = mass_profile(scene, x_bins=x_bins, mask=column)

    _write_front(out / f"{args.name}_front.csv", times, fronts, eks)

    fig, ax = plt.subplots(figsize=(8, 3.2))
    for t, prof in profiles.items():
        ax.plot(prof.x_centres, prof.height, label=f"t = {t:.2f} s")
    ax.set_xlabel("x along the slope (m)")
    ax.set_ylabel("h (m)")
    ax.set_title(
        f"2D collapse, {column.sum()} discs, slope {args.slope:g} deg, mu {args.mu:g}, rough bed"
    )
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / f"{args.name}_profiles.png", dpi=120)

    fig, ax = plt.subplots(figsize=(6, 3.2))
    ax.plot(times, np.array(fronts) - r0)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("r_f - R0 (m)")
    ax.set_title("Front position")
    fig.tight_layout()
    fig.savefig(out / f"{args.name}_front.png", dpi=120)

    runout = (fronts[-1] - r0) / r0
    at_rest = ek < args.rest * released
    summary = (
        f"{'At rest' if at_rest else 'NOT at rest (stopped at the --t-max cap)'}: "
        f"t = {scene.time:.3f} s after {stepper.step_count} steps "
        f"({time.perf_counter() - start:.0f} s); main-mass kinetic energy {ek:.2e} J/m, "
        f"{ek / max(released, 1e-300):.1e} of the potential energy released; "
        f"front moved {fronts[-1] - r0:.3f} m, runout (L_f - L0) / L0 = {runout:.3f}; "
        f"front velocity {_front_speed(times, fronts):.3f} m/s over the last 0.5 s "
        f"(at most {_front_speed(times, fronts, max_over=0.05):.2f} m/s over 0.05 s)."
    )
    print(summary)
    write_meta(
        out,
        args.name,
        title=f"A 2D collapse on a {args.slope:g} degree slope",
        files=[out / f"{args.name}_{k}" for k in ("profiles.png", "front.png", "front.csv")],
        summary=summary,
    )


def _write_front(path: Path, times: list[float], fronts: list[float], eks: list[float]) -> None:
    """t, front position r_f and the main mass's kinetic energy (J/m) per step."""
    pd.DataFrame({"t": times, "front": fronts, "ek_main": eks}).to_csv(path, index=False)


def _front_speed(
    times: list[float], fronts: list[float], window: float = 0.5, max_over: float | None = None
) -> float:
    """Mean front velocity over the last ``window`` seconds or, with ``max_over``, the
    largest mean velocity over any ``max_over``-second window of the run."""
    t, f = np.asarray(times), np.asarray(fronts)
    if max_over is None:
        k = int(np.searchsorted(t, t[-1] - window))
        return float((f[-1] - f[k]) / max(t[-1] - t[k], 1e-300))
    k = np.searchsorted(t, t - max_over)
    ok = t - t[k] > 0
    return float(np.max((f - f[k])[ok] / (t - t[k])[ok])) if ok.any() else 0.0


def _subset(scene: cocd.Scene, mask: np.ndarray) -> cocd.Scene:
    sub = cocd.Scene(
        scene.positions[mask],
        scene.radii[mask],
        density=scene.density[mask],
        velocities=scene.velocities[mask],
        angular_velocities=scene.angular_velocities[mask],
        gravity=scene.gravity,
    )
    return sub


def _potential(scene: cocd.Scene, mask: np.ndarray) -> float:
    return float(-np.sum(scene.masses[mask] * (scene.positions[mask] @ scene.gravity)))


if __name__ == "__main__":
    main()
