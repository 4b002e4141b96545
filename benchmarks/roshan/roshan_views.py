"""Thesis figure 4-5: baseline vs ROSHAN error against the number of views and their yaw range.

For each seed, ``--objects`` random car-sized ellipsoids (thesis: 20) are drawn; each is seen
from ``n`` views whose azimuths around it follow a Gaussian clipped to a yaw range of width
``w`` (``N(0, (w/4)^2)`` clipped to ``[-w/2, w/2]`` around a random base azimuth; distance 8-14 m,
camera 1.5 m up: :func:`jaxsem.slam.sim.simulate_views`). The same ellipsoids and the same standard
normal draws are used in every (n, w) cell (common random numbers), so the cells differ only by
the view geometry. Each problem (the n views, one object) is solved by both systems with the
structured Levenberg-Marquardt (:func:`jaxsem.slam.solve_schur`, ``--steps`` iterations),
everything vmapped in one jitted call per system.

Noise (the ``thesis`` stand-in preset, :func:`jaxsem.slam.sim.thesis_config`): box edges 2 px, pose
prior 5 cm / 1 deg, texture depth 0.1 m + 1 % of depth. Initial ellipsoids (``--init``):
``single_view`` (default) is each system's initialisation from the first view, as the online
system creates an object (section 4.3.5; the same rule as the ``quadricslam`` preset of
``roshan_table41.py``): the baseline on the ray at 10 m depth with identity rotation and radii
1 m, ROSHAN at its texture-plane depth with class-mean radii. ``noisy_truth`` starts both from
truth + N(0, 1 m) per position axis, N(0, 20 deg) yaw, N(0, 0.3 m) per radius; then a single
view cannot show the shape prior's benefit (both keep the nearly true initial radii).

Also reported: the mean square of the whitened pose-prior residual
(:func:`jaxsem.factors.pose_prior_residual`) at the true poses, per translation and rotation
component; 1 when the solver's pose noise model matches the simulator's noise.

Reported per cell: the median over all ellipsoids of the shape (m), position (m) and
orientation (deg) errors (:func:`jaxsem.metrics.ellipsoid_errors`). Writes
``results/roshan_views.{json,md,png}`` (heat maps laid out as the thesis figure: rows shape and
position, columns baseline and ROSHAN).

    python benchmarks/roshan/roshan_views.py --objects 20 --seeds 0,1,2
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
import _harness

from jaxsem.slam._batch import solve_schur  # layers: white-box

METRICS = ("shape", "position", "orientation")
UNITS = {"shape": "m", "position": "m", "orientation": "deg"}
SYSTEMS = ("baseline", "roshan")
INIT_TEXT = {
    "single_view": "each system's own from the first view: baseline at 10 m depth, identity "
    "rotation, radii 1 m; ROSHAN at the texture depth with class-mean radii",
    "noisy_truth": "truth + N(0, 1 m) position, N(0, 20 deg) yaw, N(0, 0.3 m) radii for both",
}


def _numbers(text, name, kind=float):
    """A comma list of ``kind`` values from the command line (at least one)."""
    try:
        values = [kind(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise SystemExit(f"{name}: expected a comma list of {kind.__name__}s, got {text!r}") from None
    if not values:
        raise SystemExit(f"{name}: expected at least one value")
    return values


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--objects", type=int, default=20, help="ellipsoids per seed (thesis: 20)")
    p.add_argument("--seeds", default="0", help="comma list of seeds; the medians pool all seeds")
    p.add_argument("--views", default="1,2,3,5,8,12", help="comma list of numbers of views")
    p.add_argument("--yaw-ranges", default="0,15,30,60,90,180,360", help="comma list of yaw range widths (deg)")
    p.add_argument("--steps", type=int, default=50, help="LM iterations per solve")
    p.add_argument(
        "--init",
        choices=("single_view", "noisy_truth"),
        default="single_view",
        help="initial ellipsoids (see the module docstring)",
    )
    p.add_argument(
        "--pose-noise-deg",
        type=float,
        default=None,
        help="override the pose prior's rotation noise (deg per axis; preset 1.0)",
    )
    _harness.output_arguments(p, "roshan_views", ".json / .md / .png", float32=True)
    args = p.parse_args(argv)
    args.seed_list = _numbers(args.seeds, "--seeds", kind=int)
    args.view_list = _numbers(args.views, "--views", kind=int)
    args.yaw_list = _numbers(args.yaw_ranges, "--yaw-ranges")
    if args.objects < 1 or args.steps < 1 or min(args.view_list) < 1:
        raise SystemExit("--objects, --steps and every --views entry must be positive")
    if args.pose_noise_deg is not None and not args.pose_noise_deg >= 0:
        raise SystemExit("--pose-noise-deg: expected a number >= 0")
    if min(args.yaw_list) < 0 or max(args.yaw_list) > 360:
        raise SystemExit("--yaw-ranges: expected widths in [0, 360] degrees")
    return args


def sim_config(args):
    from jaxsem.slam import sim

    changes = {"init_mode": "single_view", "init_radii": 1.0} if args.init == "single_view" else {}
    if args.pose_noise_deg is not None:
        changes["pose_noise_deg"] = args.pose_noise_deg
    return sim.thesis_config("orbit", **changes)


def make_solver(system, cfg, max_views, steps, init_mode):
    """A jitted function ``(keys (B,), views (B,), yaw (B,) rad) -> {metric: (B,)}`` for one system."""
    import jax
    import jax.numpy as jnp

    from jaxsem import factors, slam
    from jaxsem.slam import sim

    sc = sim.solver_config(system, cfg, max_steps=steps)

    def one(key, n, yaw):
        m = sim.simulate_views(key, n, yaw, cfg, max_views=max_views)
        problem = sim.to_problem(m, cfg)
        init = sim.initial_estimate(m)
        if init_mode == "single_view" and system == sim.ROSHAN:
            init = slam.initialize(problem, sc)  # texture depth, class-mean radii
        est, info = solve_schur(problem, init, sc)
        err = sim.map_errors(est, m)
        # Pose-prior residual at the true poses (noise-model check), over the active views.
        r = factors.pose_prior_residual(
            m.camera_T_world, m.pose_prior, sc.noise.pose_rotation_sigma, sc.noise.pose_translation_sigma
        )
        w = (jnp.arange(max_views) < n).astype(r.dtype)[:, None]
        chi = jnp.sum(w * r**2, axis=0) / jnp.maximum(jnp.sum(w), 1.0)
        return {
            **{k: err[k] for k in METRICS},
            "count": err["count"],
            "steps": info.steps,
            "pose_chi2_translation": jnp.mean(chi[:3]),
            "pose_chi2_rotation": jnp.mean(chi[3:]),
        }

    return jax.jit(jax.vmap(one))


def run(args):
    """Returns ``{system: {metric: (V, Y, S * objects) array}}`` and seconds per system."""
    import jax
    import jax.numpy as jnp

    cfg = sim_config(args)
    V, Y = len(args.view_list), len(args.yaw_list)
    keys = jnp.stack([jax.random.split(jax.random.key(s), args.objects) for s in args.seed_list]).reshape(
        -1
    )  # (N,) the same ellipsoids in every cell
    N = keys.shape[0]
    views = jnp.asarray(args.view_list, jnp.int32)[:, None, None]
    yaw = jnp.deg2rad(jnp.asarray(args.yaw_list))[None, :, None]
    flat_keys = jnp.broadcast_to(keys[None, None, :], (V, Y, N)).reshape(-1)
    flat_views = jnp.broadcast_to(views, (V, Y, N)).reshape(-1)
    flat_yaw = jnp.broadcast_to(yaw, (V, Y, N)).reshape(-1).astype(jnp.result_type(float))
    out, seconds = {}, {}
    for system in SYSTEMS:
        solve = make_solver(system, cfg, max(args.view_list), args.steps, args.init)
        start = time.perf_counter()
        res = jax.block_until_ready(solve(flat_keys, flat_views, flat_yaw))
        seconds[system] = time.perf_counter() - start
        out[system] = {k: np.asarray(v).reshape(V, Y, N) for k, v in res.items()}
        print(f"[{system}] {V * Y * N} problems in {seconds[system]:.1f} s (compilation included)", flush=True)
    return out, seconds


def medians(res):
    """{system: {metric: (V, Y) median over ellipsoids}} (only objects that were detected)."""
    out = {}
    for system, r in res.items():
        seen = r["count"] > 0
        out[system] = {
            k: np.array(
                [
                    [np.median(r[k][i, j][seen[i, j]]) if seen[i, j].any() else np.nan for j in range(r[k].shape[1])]
                    for i in range(r[k].shape[0])
                ]
            )
            for k in METRICS
        }
        for q in (25, 75):
            out[system].update(
                {
                    f"{k}_p{q}": np.array(
                        [
                            [
                                np.percentile(r[k][i, j][seen[i, j]], q) if seen[i, j].any() else np.nan
                                for j in range(r[k].shape[1])
                            ]
                            for i in range(r[k].shape[0])
                        ]
                    )
                    for k in ("shape", "position")
                }
            )
        out[system]["detected_fraction"] = seen.mean(-1)
    return out


def trend_checks(med, views, yaws):
    """The thesis' claims as checks: list of (claim, held, detail)."""
    b, r = med["baseline"], med["roshan"]
    checks = []
    i1 = views.index(min(views))
    s_b, s_r = np.nanmean(b["shape"][i1]), np.nanmean(r["shape"][i1])
    checks.append(
        (
            f"ROSHAN's shape error is small with {min(views)} view(s) (below the baseline's)",
            bool(s_r < s_b),
            f"mean over yaw ranges: ROSHAN {s_r:.2f} m vs baseline {s_b:.2f} m",
        )
    )
    low = np.array([[v <= 3 or w <= 30 for w in yaws] for v in views])
    for metric in ("shape", "position"):
        better = (r[metric] <= b[metric])[low]
        checks.append(
            (
                f"ROSHAN {metric} error <= baseline's in the low-diversity cells (<= 3 views or <= 30 deg)",
                bool(better.all()),
                f"{int(better.sum())} of {better.size} cells",
            )
        )
    for metric in ("shape", "position"):
        lo, hi = b[metric][0, 0], b[metric][-1, -1]
        checks.append(
            (
                f"the baseline's {metric} error falls with more views over a wider range",
                bool(hi < lo),
                f"{lo:.2f} m at ({views[0]} views, {yaws[0]:g} deg) -> {hi:.2f} m at "
                f"({views[-1]} views, {yaws[-1]:g} deg)",
            )
        )
    return checks


def plot(med, args, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5), constrained_layout=True)
    for row, metric in enumerate(("shape", "position")):
        vmax = max(np.nanmax(med[s][metric]) for s in SYSTEMS)
        for col, system in enumerate(SYSTEMS):
            ax = axes[row, col]
            data = med[system][metric]
            im = ax.imshow(data, origin="lower", cmap="viridis", vmin=0.0, vmax=vmax, aspect="auto")
            for i in range(data.shape[0]):
                for j in range(data.shape[1]):
                    v = data[i, j]
                    ax.text(
                        j,
                        i,
                        f"{v:.2f}",
                        ha="center",
                        va="center",
                        fontsize=7,
                        color="white" if v < 0.6 * vmax else "black",
                    )
            ax.set_xticks(range(len(args.yaw_list)), [f"{w:g}" for w in args.yaw_list])
            ax.set_yticks(range(len(args.view_list)), [str(v) for v in args.view_list])
            ax.set_xlabel("yaw range of the views (deg)")
            ax.set_ylabel("number of views")
            ax.set_title(f"{'ROSHAN' if system == 'roshan' else 'baseline'}: median {metric} error (m)", fontsize=10)
        fig.colorbar(im, ax=axes[row, :].tolist(), shrink=0.9, label=f"{metric} error (m)")
    n = args.objects * len(args.seed_list)
    fig.suptitle(
        f"View diversity (thesis fig. 4-5): {n} ellipsoids, init {args.init}, {args.steps} LM steps", fontsize=11
    )
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _table(med, system, metric, args):
    head = "| views \\ yaw range (deg) | " + " | ".join(f"{w:g}" for w in args.yaw_list) + " |"
    lines = [head, "|" + "---|" * (len(args.yaw_list) + 1)]
    for i, v in enumerate(args.view_list):
        lines.append(f"| {v} | " + " | ".join(f"{x:.2f}" for x in med[system][metric][i]) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    args = parse_args(argv)
    import jax

    if not args.float32:
        jax.config.update("jax_enable_x64", True)
    from jaxsem.cli import enable_compilation_cache

    enable_compilation_cache()
    t0 = time.perf_counter()
    res, seconds = run(args)
    med = medians(res)
    checks = trend_checks(med, args.view_list, args.yaw_list)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    png = out / f"{args.name}.png"
    plot(med, args, png)

    command = "python benchmarks/roshan/roshan_views.py " + " ".join(sys.argv[1:] if argv is None else argv)
    date = subprocess.run(["date", "-u"], capture_output=True, text=True).stdout.strip()
    failed = [c for c in checks if not c[1]]
    if failed:
        behind = (
            "Where we are behind: the thesis' trend is not reproduced in: "
            + "; ".join(f"{c[0]} ({c[2]})" for c in failed)
            + "."
        )
    else:
        behind = (
            "Where we are behind: nowhere on the thesis' trend (ROSHAN better with few views "
            "and a small yaw range; the baseline needs more views from a wider range)."
        )
    payload = {
        "command": command,
        "date": date,
        "machine": "2-core CPU (shared, noisy)",
        "args": {k: v for k, v in vars(args).items() if k not in ("seed_list", "view_list", "yaw_list")},
        "views": args.view_list,
        "yaw_ranges_deg": args.yaw_list,
        "ellipsoids_per_cell": args.objects * len(args.seed_list),
        "seconds": seconds,
        "pose_prior_chi2_at_truth": {
            "translation": float(np.mean(res["roshan"]["pose_chi2_translation"])),
            "rotation": float(np.mean(res["roshan"]["pose_chi2_rotation"])),
        },
        "median": {s: {k: np.round(np.asarray(v), 4).tolist() for k, v in med[s].items()} for s in SYSTEMS},
        "note": "median[system][metric][i][j]: median over ellipsoids at views[i], yaw_ranges_deg[j]; "
        "*_p25 / *_p75: quartiles; detected_fraction: share of ellipsoids with a detection",
        "trend_checks": [{"claim": c[0], "held": c[1], "detail": c[2]} for c in checks],
        "median_steps": {s: float(np.median(res[s]["steps"])) for s in SYSTEMS},
    }
    (out / f"{args.name}.json").write_text(json.dumps(payload, indent=1, default=float))
    n = args.objects * len(args.seed_list)
    md = [
        "## ROSHAN view diversity (thesis figure 4-5)" + ("" if args.name == "roshan_views" else f": {args.name}"),
        "",
        f"Command: `{command}`  ",
        f"Date: {date}  ",
        "Machine: 2-core CPU (shared, noisy)",
        "",
        f"{n} random car ellipsoids (seeds {args.seeds}), each seen from n views whose azimuths follow "
        "a Gaussian clipped to the yaw range (sigma = range / 4, clipped to +-range / 2, random base "
        "azimuth, 8-14 m away); the same ellipsoids and noise draws in every cell. Both systems "
        f"solve each problem with {args.steps} Schur-LM steps from the `{args.init}` initialisation "
        f"({INIT_TEXT[args.init]}; thesis preset noise: boxes 2 px, poses 5 cm / "
        f"{sim_config(args).pose_noise_deg:g} deg, texture 0.1 m + 1 %). Cells: median over the "
        "ellipsoids; rows = number of views, columns = "
        f"yaw range (deg). Figure: `{png.name}`. Time: baseline {seconds['baseline']:.0f} s, ROSHAN "
        f"{seconds['roshan']:.0f} s for {len(args.view_list) * len(args.yaw_list) * n} problems each "
        "(compilation included).",
        "",
    ]
    if args.pose_noise_deg is not None:
        md += [
            f"Variant: the pose prior's rotation noise is {args.pose_noise_deg:g} deg per axis "
            "(`--pose-noise-deg`; the preset's is 1 deg). With no rotation noise the simulated pose "
            "error is a pure translation, which the solver's pose-prior residual models exactly "
            "(noise-model check below), so this run isolates the effect of that model.",
            "",
        ]
    for metric in ("shape", "position"):
        for system in SYSTEMS:
            md += [f"Median {metric} error (m), {system}:", "", _table(med, system, metric, args), ""]
    chi_t = float(np.mean(res["roshan"]["pose_chi2_translation"]))
    chi_r = float(np.mean(res["roshan"]["pose_chi2_rotation"]))
    md += [
        f"Noise-model check: mean square of the whitened pose-prior residual at the true poses = "
        f"{chi_t:.1f} per translation component and {chi_r:.2f} per rotation component (1 if the "
        "solver's pose-prior model matched the simulated pose noise).",
        "",
    ]
    md += [
        f"Median LM steps taken (cap {args.steps}): baseline "
        f"{float(np.median(res['baseline']['steps'])):g}, ROSHAN {float(np.median(res['roshan']['steps'])):g} "
        "(the baseline's nearly degenerate problems often run to the cap; a spot check at 150 steps "
        "moved cell medians by at most about 0.15 m).",
        "",
    ]
    md += ["Thesis trend checks:", ""]
    md += [f"- {'held' if c[1] else 'NOT reproduced'}: {c[0]} ({c[2]})" for c in checks]
    grow = med["roshan"]["position"][-1, 0] / max(med["roshan"]["position"][0, 0], 1e-9)
    if grow > 1.2:
        md += [
            "",
            f"Not in the thesis' figure: at a {args.yaw_list[0]:g} deg yaw range ROSHAN's position error "
            f"grows with the number of views ({med['roshan']['position'][0, 0]:.2f} m with "
            f"{args.view_list[0]} -> {med['roshan']['position'][-1, 0]:.2f} m with {args.view_list[-1]}), "
            "as the baseline's does; it coincides with the pose-prior noise-model mismatch above "
            "(the `--pose-noise-deg 0` variant, `roshan_views_norot`, isolates it).",
        ]
    md += ["", behind, ""]
    (out / f"{args.name}.md").write_text("\n".join(md))
    print("\n".join(md))
    print(f"wrote {out / args.name}.{{json,md,png}} in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
