"""Spheres settling in a viscous fluid: the coupling hook with a simple drag law.

Usage::

    python examples/settling_in_fluid.py [--n 27] [--viscosity 0.5] [--fluid-density 1000]

A fluid solver coupled to cocd gives, every step, a force on each grain and
reads back the contact impulses (:mod:`cocd.coupling`). Here the "fluid" is a
still liquid of viscosity ``eta`` and density ``rho_f``: on a sphere of
diameter ``d`` and velocity ``v`` it exerts Stokes drag ``-3 pi eta d v`` and
buoyancy ``rho_f V g`` upwards. Its loads are given to the stepper by a
callable (``Stepper(external=loads)``), evaluated at the start of each step
from the grains' current velocities.

``n`` spheres start on a wide lattice above the floor of a box. Each falls,
reaches the terminal velocity ``v_T = (m - rho_f V) g / (3 pi eta d)``, lands
and comes to rest on the others. The script prints the fastest fall speed
against ``v_T``, and at the end the floor's load from the contact impulses
(:meth:`cocd.Stepper.contact_impulses`), which must be the spheres' buoyant
weight ``sum (m - rho_f V) g``: what the fluid solver would read back.
"""

from __future__ import annotations

import argparse

import numpy as np

import cocd
from cocd.coupling import Loads


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--n", type=int, default=27, help="spheres (a cube number fills the lattice)"
    )
    parser.add_argument("--diameter", type=float, default=0.004)
    parser.add_argument("--viscosity", type=float, default=0.5, help="Pa s (glycerol-water)")
    parser.add_argument("--fluid-density", type=float, default=1000.0)
    parser.add_argument("--dt", type=float, default=1e-3)
    parser.add_argument("--until", type=float, default=2.0)
    parser.add_argument("--solver", default="clarabel")
    args = parser.parse_args()

    d, g = args.diameter, 9.81
    side = int(np.ceil(args.n ** (1.0 / 3.0)))
    grid = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    spacing = 2.5 * d
    positions = (grid[: args.n] + 0.5) * spacing
    positions[:, 2] += 0.002  # 2 mm above the floor
    box = side * spacing
    walls = [
        cocd.Wall((0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
        cocd.Wall((0.0, 0.0, 0.0), (1.0, 0.0, 0.0)),
        cocd.Wall((box, 0.0, 0.0), (-1.0, 0.0, 0.0)),
        cocd.Wall((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
        cocd.Wall((0.0, box, 0.0), (0.0, -1.0, 0.0)),
    ]
    scene = cocd.Scene(positions, d / 2.0, walls=walls, mu=0.3)
    volume = np.pi * d**3 / 6.0
    gamma = 3.0 * np.pi * args.viscosity * d  # Stokes drag coefficient (N s/m)
    buoyancy = args.fluid_density * volume * g
    m = float(scene.masses[0])
    v_terminal = (m * g - buoyancy) / gamma

    def loads(s: cocd.Scene, t: float) -> Loads:
        forces = -gamma * s.velocities
        forces[:, 2] += buoyancy
        return Loads(forces=forces)

    stepper = cocd.Stepper(scene, args.dt, solver=args.solver, external=loads)
    fastest = 0.0
    while scene.time < args.until - 1e-12:
        stepper.step()
        fastest = max(fastest, float(-scene.velocities[:, 2].min()))
    impulse, _ = stepper.contact_impulses()
    # Net contact force on the spheres = the floor's (and walls') reaction.
    carried = float(impulse[:, 2].sum()) / args.dt
    weight = args.n * (m * g - buoyancy)
    print(
        f"{args.n} spheres, d = {d * 1e3:g} mm, eta = {args.viscosity:g} Pa s, "
        f"rho_f = {args.fluid_density:g} kg/m3, dt = {args.dt:g} s, t = {scene.time:.3f} s"
    )
    print(
        f"terminal velocity (Stokes): {v_terminal:.6g} m/s; fastest fall: {fastest:.6g} m/s "
        f"(ratio {fastest / v_terminal:.6f})"
    )
    print(
        f"load carried by the contacts: {carried:.6g} N; buoyant weight: {weight:.6g} N "
        f"(ratio {carried / weight:.6f})"
    )
    print(f"largest speed at the end: {np.abs(scene.velocities).max():.3g} m/s")


if __name__ == "__main__":
    main()
