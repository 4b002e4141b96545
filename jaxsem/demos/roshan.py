"""ROSHAN demo: a forward flight past parked cars, baseline vs ROSHAN (thesis 4.4, Forward path).

Simulates :func:`jaxsem.slam.sim.quadricslam_config` Forward maps (cars within 15 deg of the flight
direction, a camera 1.5 m up flying a straight line past them; box noise 3 px, pose prior
5 cm / 1 deg, one texture plane per box), and solves every map with both systems of
:func:`jaxsem.slam.sim.solver_config` under the online protocol of :func:`jaxsem.slam.sim.solve_online`
(re-optimised every 10 frames):

- baseline: pose priors + box factors (+ a weak shape regulariser); objects start as
  QuadricSLAM starts them (first box, 10 m depth, identity rotation, radii 1 m);
- ROSHAN: + texture-plane factor + class shape prior; objects start from ROSHAN's single-view
  initialisation (texture depth, class-mean radii, section 4.3.5).

Returns a markdown table of the median over maps of each map's mean shape (m), position (m) and
orientation (deg, symmetry-aware) error, and writes ``roshan_forward.png``: a top-down view of
the first map (true ellipsoids, both estimates, the camera path).

``quick``: 1 map of 4 cars and 30 frames (seconds, mostly compilation);
otherwise 16 maps of 10 cars and 60 frames (the Table 4.1 setting at a small scale).
"""

from __future__ import annotations

import pathlib
import time

import jax
import numpy as np

from .. import slam
from ..scripting import atomic_savefig
from ..slam import sim

METRICS = ("shape", "position", "orientation")
UNITS = {"shape": "m", "position": "m", "orientation": "deg"}


def simulate_and_solve(seed: int, num_maps: int, cfg, *, every: int = 10, steps: int = 10):
    """Simulates ``num_maps`` maps of ``cfg`` and solves them with both systems.

    Returns:
      ``(maps, estimates, errors, seconds)``: the :class:`jaxsem.slam.sim.SimulatedMap` batch (leading
      axis M), ``{system: SlamEstimate}`` (leading axis M), ``{system: {metric: (M,) array,
      "count": (M,)}}`` and ``{system: seconds}`` (compilation included).
    """
    maps = sim.simulate_batch(seed, num_maps, cfg)
    estimates, errors, seconds = {}, {}, {}
    for system in (sim.BASELINE, sim.ROSHAN):
        sc = sim.solver_config(system, cfg, max_steps=steps)

        def one(m, c, system=system):  # everything in one jit: eager ops compile one by one
            problem = sim.to_problem(m, cfg)
            init = sim.initial_estimate(m)
            if system == sim.ROSHAN and cfg.init_mode == "single_view":
                init = slam.initialize(problem, c)
            est, _ = sim.solve_online(problem, init, c, every=every, init_radii=init.radii)
            return est, sim.map_errors(est, m)

        start = time.perf_counter()
        est, err = jax.jit(jax.vmap(one, in_axes=(0, None)))(maps, sc)
        errors[system] = jax.tree_util.tree_map(np.asarray, jax.block_until_ready(err))
        estimates[system] = est
        seconds[system] = time.perf_counter() - start
    return maps, estimates, errors, seconds


def error_table(errors, seconds=None) -> str:
    """Markdown table of the median over maps of the per-map mean errors, one row per system."""
    head = "| system | " + " | ".join(f"{m} ({UNITS[m]})" for m in METRICS) + " | objects scored |"
    if seconds is not None:
        head += " time (s) |"
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for system, err in errors.items():
        row = f"| {system} | " + " | ".join(f"{float(np.median(err[m])):.2f}" for m in METRICS)
        row += f" | {int(np.sum(err['count']))} |"
        if seconds is not None:
            row += f" {seconds[system]:.1f} |"
        lines.append(row)
    return "\n".join(lines)


def plot_map(maps, estimates, index: int, path: pathlib.Path, title: str) -> None:
    """Top-down figure of map ``index``: truth (black), baseline (red dashed), ROSHAN (blue),
    each estimate joined to its true centre by a dotted line, and the camera path (green)."""
    import matplotlib  # deferred: matplotlib is optional (the sim extra)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: matplotlib is optional (the sim extra)

    one = lambda x: np.asarray(x[index])
    observed = one(maps.observed)
    fig, ax = plt.subplots(figsize=(11, 5.2))
    truth = jax.tree.map(one, maps.ellipsoid)
    slam.draw_top_down(
        ax,
        truth,
        one(maps.object_mask) & ~observed,
        color="0.6",
        ls=":",
        lw=1.0,
        label="never detected",
    )
    slam.draw_top_down(
        ax,
        truth,
        observed,
        color="k",
        lw=2.0,
        label="truth",
    )
    styles = {sim.BASELINE: dict(color="tab:red", ls="--", lw=1.3), sim.ROSHAN: dict(color="tab:blue", lw=1.3)}
    for system, est in estimates.items():
        slam.draw_top_down(ax, jax.tree.map(one, est.ellipsoid), observed, label=system, **styles[system])
        truth, guess = one(maps.object_center)[observed], one(est.center)[observed]
        for a, b in zip(guess, truth):  # each estimate joined to its true centre
            ax.plot([a[0], b[0]], [a[1], b[1]], ":", color=styles[system]["color"], lw=0.8)
        ax.plot(guess[:, 0], guess[:, 1], ".", color=styles[system]["color"], ms=4)
    slam.draw_camera_path(ax, one(maps.camera_T_world), color="tab:green", label="camera path")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), fontsize=8, ncol=5, frameon=False)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)


def run(out_dir: pathlib.Path, quick: bool) -> str:
    """Runs the demo; writes ``roshan_forward.png`` into ``out_dir``; returns the table."""
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if quick:
        num_maps, cfg = 1, sim.quadricslam_config("forward", num_objects=4, num_frames=30, forward_step=0.75 * 59 / 29)
    else:
        num_maps, cfg = 16, sim.quadricslam_config("forward")
    t0 = time.perf_counter()
    maps, estimates, errors, seconds = simulate_and_solve(0, num_maps, cfg)
    path = out_dir / "roshan_forward.png"
    e = {s: {m: float(errors[s][m][0]) for m in METRICS} for s in errors}
    plot_map(
        maps,
        estimates,
        0,
        path,
        f"Forward flight, map 0 of {num_maps}: position error baseline "
        f"{e['baseline']['position']:.2f} m, ROSHAN {e['roshan']['position']:.2f} m "
        f"(shape {e['baseline']['shape']:.2f} vs {e['roshan']['shape']:.2f} m)",
    )
    lines = [
        f"ROSHAN demo: Forward flight past {cfg.num_objects} cars, {cfg.num_frames} frames, "
        f"{num_maps} map(s); median over maps of each map's mean error "
        f"({time.perf_counter() - t0:.0f} s incl. compilation)",
        "",
        error_table(errors, seconds),
        "",
        f"figure: {path}",
    ]
    return "\n".join(lines)
