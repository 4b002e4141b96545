"""VoluMon-initialised ROSHAN (thesis section 6.3) against ROSHAN's own initialisation, Forward path.

Claim tested: new landmarks that start from VoluMon's single-view ellipsoid (chapter 5) instead of
ROSHAN's single-view initialisation (section 4.3.5: class-mean shape, identity orientation, on the
box's ray at the texture-plane depth) have lower error early (after the first detection, after 5)
and no higher error at the end, once boxes and texture planes refine them online (section 4.3.6).

Setting: a Forward path at VoluMon's scale (the shipped model ``volumon_fast``: tabletop classes
cracker_box, ball, melon, soup_can; 128 x 96 images, f = 110 px, trained at 0.45-1.1 m depth).
``jaxsem.slam.sim.SimConfig`` scaled down from the car preset: 10 objects (random yaw) on a 1.4 x 1.4 m
patch (the flight line kept 0.1 m clear), camera 0.15 m above the ground moving 4 cm per frame along
+x for 80 frames (from 1.3 m before the patch to 0.5 m beyond it), box noise 1 px, 3 px border
margin, texture depth 1 cm + 1 %, pose prior 5 mm / 0.5 deg. Four settings (``VARIANTS``):
"main" detects objects up to 1.1 m depth (the model's training range), so at 0.4-1.1 m; "far" up
to 1.5 m (first detections beyond the training range: VoluMon's depth saturates near 1.2 m); "boxes
only" is "main" without the texture-plane factor (ROSHAN's own init then sits at its 1.0 m default
depth); "exact VoluMon box" is "main" with a noise-free input box for the network. A third
initialisation, "VoluMon centre", takes only VoluMon's centre (identity rotation, class-mean radii,
as ROSHAN's own init) to tell which part of the network's estimate helps or hurts. Setting chosen
on seeds 0-1 (the depth range after a probe of VoluMon's depth error against depth).

Per map (seed ``--seed + i``): the simulator's noisy boxes and texture planes are the detections
of both systems (the SAME frames); at each object's first detection, VoluMon sees a stereo pair
rendered with its own exact ray caster (``jaxsem.volumon.render_object_stereo``: the object at its
true camera-frame pose, random background) and the box of the rendered shape with the same box
noise; its camera-frame ellipsoid goes to the world through the odometry pose
(``jaxsem.mapping.volumon_initial_ellipsoids``) and starts the object
(``jaxsem.slam.make_frame(..., init_*)``). Both systems run ``jaxsem.slam.online_update``
(optimise every 5 frames, 3 LM steps, all poses in the window) and a final
``online_optimize`` (50 steps).

Errors (``jaxsem.metrics.ellipsoid_errors``, symmetry-aware): an object's error after its k-th
detection is its estimate at the end of that frame's update (k = 0: the initial ellipsoid
itself); per map the mean over the objects with at least k detections, then the median over
maps (the thesis' protocol, ``jaxsem.slam.sim.map_errors``). "End" = after the final optimisation.
Collapse: ``benchmarks/roshan/roshan_vs_quadricslam.py`` counts a map as collapsed when its mean object
position error exceeds 2 m on a 30 m patch; at this scale the same rule is 2 m x 1.4/30 = 0.09 m,
counted here per object at the end (and per map).

Run: ``python benchmarks/roshan/roshan_volumon_init.py --maps 12 --seed 100`` (tuning, if any: seeds 0-2).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import subprocess
import time

import jax

from jaxsem.slam._solver_config import NoiseModel  # layers: white-box

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from jaxsem import classes, mapping, metrics, quadrics, slam, volumon  # noqa: E402
from jaxsem.slam import sim  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
BENCH = HERE.parent  # benchmarks/: the shared results folder and _harness
NAME = "roshan_volumon_init"
KS = (0, 1, 2, 3, 5, 8, 10, 15, 20)  # detections after which the error is recorded (0 = init)
PATCH = 1.4
COLLAPSE_M = 2.0 * PATCH / 30.0  # the repo's 2 m collapse rule on a 30 m patch, scaled


#: (name, max detection depth m, texture planes on, box noise of VoluMon's input box on): main first
VARIANTS = (
    ("main", 1.1, True, True),
    ("exact VoluMon box", 1.1, True, False),
    ("far", 1.5, True, True),
    ("boxes only", 1.1, False, True),
)
VARIANT_NOTES = {
    "main": "objects detected up to 1.1 m, the shipped model's training range (0.45-1.1 m); boxes + texture planes",
    "exact VoluMon box": "as main, but VoluMon's input box is the rendered shape's exact box (no 1 px noise; "
    "ROSHAN's boxes stay noisy): what the box noise costs the network on boxes of 7-25 px",
    "far": "detected up to 1.5 m: first detections beyond the model's training range; boxes + texture planes",
    "boxes only": "up to 1.1 m, no texture-plane factor: ROSHAN's own init puts new objects at its default "
    "depth (1.0 m, mid-range), as section 4.3.5 does without a texture plane",
}


def sim_config(args, max_depth: float = 1.1) -> sim.SimConfig:
    return sim.SimConfig(
        path="forward",
        num_objects=10,
        classes=tuple(volumon.VOLUMON_CLASS_NAMES),
        patch_size=PATCH,
        corridor_half_width=0.1,
        object_gap=0.05,
        yaw_range=float(np.pi),
        num_frames=args.frames,
        image_width=128,
        image_height=96,
        focal=110.0,
        camera_height=0.15,
        forward_step=0.04,
        forward_end_margin=0.5,
        box_noise_px=1.0,
        border_margin_px=3.0,
        min_box_px=4.0,
        max_depth=max_depth,
        texture_noise_m=0.01,
        texture_noise_rel=0.01,
        pose_noise_m=0.005,
        pose_noise_deg=0.5,
        init_depth=1.0,
        init_radii=None,
    )


def solver_config(cfg: sim.SimConfig, use_texture: bool = True) -> slam.SolverConfig:
    noise = NoiseModel(
        pose_rotation_sigma=float(np.deg2rad(cfg.pose_noise_deg)),
        pose_translation_sigma=cfg.pose_noise_m,
        box_sigma=cfg.box_noise_px,
        texture_sigma=cfg.texture_noise_m + 1.0 * cfg.texture_noise_rel,
    )
    return slam.SolverConfig(
        noise=noise,
        border_margin=cfg.border_margin_px,
        default_depth=cfg.init_depth,
        min_depth=0.05,
        use_texture=use_texture,
    )


def volumon_inits(m, cfg, model, variables, vcfg, rng, timing, box_noise=True):
    """Per object: VoluMon's world-frame ellipsoid from a stereo pair rendered at its first detection."""
    N, T = m.object_center.shape[0], m.boxes.shape[0]
    K = np.asarray(m.K)
    W, H = cfg.image_width, cfg.image_height
    out = {}
    vol_index = {classes.index(n): i for i, n in enumerate(volumon.VOLUMON_CLASS_NAMES)}
    for j in range(N):
        t = int(m.first_frame[j])
        if not bool(m.observed[j]) or t >= T:
            continue
        R_c, c_c = quadrics.camera_frame(m.object_rotation[j], m.object_center[j], m.camera_T_world[t])
        cls = vol_index[int(m.object_class[j])]
        t0 = time.perf_counter()
        view = volumon.render_object_stereo(
            np.asarray(R_c),
            np.asarray(c_c),
            np.asarray(m.object_radii[j]),
            cls,
            K,
            0.06,
            H,
            W,
            seed=int(rng.integers(1 << 31)),
        )
        box = np.asarray(view.box_left, np.float64) + box_noise * cfg.box_noise_px * rng.normal(size=4)
        box = np.clip(box, -0.5, [W - 0.5, H - 0.5, W - 0.5, H - 0.5])
        if not (box[2] - box[0] >= 2 and box[3] - box[1] >= 2):
            continue
        t1 = time.perf_counter()
        (R, c, r), ok = mapping.volumon_initial_ellipsoids(
            model,
            variables,
            vcfg,
            np.asarray(view.left),
            box[None],
            cls,
            quadrics.Camera(K, np.asarray(m.pose_prior[t])),
        )
        jax.block_until_ready(r)
        t2 = time.perf_counter()
        timing["render_s"].append(t1 - t0)
        timing["volumon_s"].append(t2 - t1)
        if bool(ok[0]):
            out[j] = (np.asarray(R[0]), np.asarray(c[0]), np.asarray(r[0]))
    return out


def frames_of(m, cfg, inits, D):
    frames = []
    T, N = m.boxes.shape[:2]
    boxes, bm = np.asarray(m.boxes), np.asarray(m.box_mask)
    tex, tm = np.asarray(m.texture_depth), np.asarray(m.texture_mask)
    cls = np.asarray(m.object_class)
    first = np.asarray(m.first_frame)
    for t in range(T):
        ids = np.flatnonzero(bm[t])
        use = np.array([int(j) in inits and first[j] == t for j in ids], bool)
        rot = np.stack([inits[j][0] if u else np.eye(3) for j, u in zip(ids, use)]) if len(ids) else np.zeros((0, 3, 3))
        cen = np.stack([inits[j][1] if u else np.zeros(3) for j, u in zip(ids, use)]) if len(ids) else np.zeros((0, 3))
        rad = np.stack([inits[j][2] if u else np.ones(3) for j, u in zip(ids, use)]) if len(ids) else np.zeros((0, 3))
        frames.append(
            slam.make_frame(
                np.asarray(m.pose_prior[t]),
                boxes[t, ids],
                cls[ids],
                ids,
                np.where(tm[t, ids], tex[t, ids], np.nan),
                max_detections=D,
                max_objects=N,
                init_rotation=rot,
                init_center=cen,
                init_radii=rad,
                init_mask=use,
            )
        )
    return frames


def run_online(m, scfg, image_size, frames, optimize_every, final_iterations=50):
    """Online ROSHAN over the frames. Returns per object the errors (position m, shape m,
    orientation deg) after each k-th detection (k in KS, NaN where fewer), at the end, the
    detection counts and the per-frame update seconds."""
    T, N = m.boxes.shape[:2]
    cap = slam.Capacity(max_poses=T, max_objects=N, max_boxes=T * N, max_detections=N)
    state = slam.online_init(scfg, cap, m.K, image_size, optimize_every=optimize_every, iterations=3)
    count = np.zeros(N, int)
    bm = np.asarray(m.box_mask)
    truth = (m.object_rotation, m.object_center, m.object_radii)
    hist = np.full((len(KS), N, 3), np.nan)
    seconds = []

    def errors(st):
        e = metrics.ellipsoid_errors(st.estimate.rotation, st.estimate.center, st.estimate.radii, *truth)
        return np.stack([np.asarray(e["position"]), np.asarray(e["shape"]), np.asarray(e["orientation"])], -1)

    for t, fr in enumerate(frames):
        t0 = time.perf_counter()
        state = slam.online_update(state, fr)
        jax.block_until_ready(state.estimate)
        seconds.append(time.perf_counter() - t0)
        count += bm[t]
        if bm[t].any():
            e = errors(state)
            for j in np.flatnonzero(bm[t]):
                if count[j] in KS:
                    hist[KS.index(int(count[j])), j] = e[j]
    before_final = errors(state)
    if final_iterations > 0:
        state = slam.online_optimize(state, final_iterations)
    return dict(hist=hist, end=errors(state), before_final=before_final, count=count, seconds=np.asarray(seconds))


def one_map(seed, cfg, scfg, vol, args, timing, box_noise=True):
    model, variables, vcfg = vol
    m = _simulate(jax.random.key(seed), config=cfg)
    m = jax.tree_util.tree_map(np.asarray, m)
    rng = np.random.default_rng([seed, 7])
    inits = volumon_inits(m, cfg, model, variables, vcfg, rng, timing, box_noise)
    N = m.object_center.shape[0]
    out = {"seed": seed, "objects": int(m.observed.sum()), "volumon_inits": len(inits)}
    # VoluMon's centre only, with ROSHAN's identity orientation and class-mean radii (what helps?)
    mean = {j: np.asarray(classes.CLASSES[int(m.object_class[j])].radii) for j in inits}
    centre_only = {j: (np.eye(3), c, mean[j]) for j, (_, c, _) in inits.items()}
    for name, use in (("roshan", {}), ("volumon", inits), ("volumon_centre", centre_only)):
        frames = frames_of(m, cfg, use, N)
        first = run_online(m, scfg, cfg.image_size, frames, optimize_every=1 << 30, final_iterations=0)
        run = run_online(m, scfg, cfg.image_size, frames, optimize_every=args.optimize_every)
        run["hist"][0] = first["end"]  # k = 0: the initial ellipsoids (inserted, never optimised)
        run["hist"][0][run["count"] == 0] = np.nan
        out[name] = run
    out["observed"] = m.observed
    return out


_simulate = jax.jit(sim.simulate, static_argnames="config")


def summarise(results, key):
    """Median over maps of each map's mean over objects; rows per k, and the end."""
    rows = {}
    for ki, k in enumerate(KS):
        per_map = [np.nanmean(r[key]["hist"][ki], axis=0) for r in results if np.isfinite(r[key]["hist"][ki]).any()]
        n_obj = sum(int(np.isfinite(r[key]["hist"][ki][:, 0]).sum()) for r in results)
        rows[k] = dict(median=np.median(per_map, axis=0).tolist() if per_map else [np.nan] * 3, objects=n_obj)
    end = [np.mean(r[key]["end"][r["observed"]], axis=0) for r in results]
    pos = np.concatenate([r[key]["end"][r["observed"], 0] for r in results])
    rows["end"] = dict(
        median=np.median(end, axis=0).tolist(),
        objects=int(len(pos)),
        collapsed_objects=int((pos > COLLAPSE_M).sum()),
        collapsed_maps=int(sum(np.mean(r[key]["end"][r["observed"], 0]) > COLLAPSE_M for r in results)),
        over_2m=int((pos > 2.0).sum()),
        ms_per_frame=float(1e3 * np.median(np.concatenate([r[key]["seconds"][1:] for r in results]))),
        ms_per_frame_mean=float(1e3 * np.mean(np.concatenate([r[key]["seconds"][1:] for r in results]))),
    )
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--maps", type=int, default=12)
    p.add_argument("--seed", type=int, default=100, help="first map seed (tune on 0-2 only)")
    p.add_argument("--frames", type=int, default=80)
    p.add_argument("--optimize-every", type=int, default=5)
    p.add_argument("--variants", default=",".join(v[0] for v in VARIANTS), help="comma-separated subset")
    p.add_argument("--out", type=pathlib.Path, default=BENCH / "results")
    p.add_argument("--tag", default=NAME)
    a = p.parse_args(argv)
    wanted = [v for v in VARIANTS if v[0] in a.variants.split(",")]
    if not wanted:
        raise SystemExit(f"--variants: expected names from {[v[0] for v in VARIANTS]}, got {a.variants!r}")
    model, variables, vcfg, meta = volumon.load_pretrained()
    runs = []
    for name, max_depth, use_texture, box_noise in wanted:
        cfg = sim_config(a, max_depth)
        scfg = solver_config(cfg, use_texture)
        timing = {"render_s": [], "volumon_s": []}
        # warm-up: one extra map compiles everything (simulate, renderer, network, the online step)
        t0 = time.perf_counter()
        one_map(10_000 + a.seed, cfg, scfg, (model, variables, vcfg), a, {"render_s": [], "volumon_s": []}, box_noise)
        warm = time.perf_counter() - t0
        results = []
        for i in range(a.maps):
            t0 = time.perf_counter()
            results.append(one_map(a.seed + i, cfg, scfg, (model, variables, vcfg), a, timing, box_noise))
            r = results[-1]
            print(
                f"[{name}] map {a.seed + i}: {r['objects']} objects, {r['volumon_inits']} VoluMon inits, "
                f"end pos roshan {np.mean(r['roshan']['end'][r['observed'], 0]):.3f} m, "
                f"volumon {np.mean(r['volumon']['end'][r['observed'], 0]):.3f} m ({time.perf_counter() - t0:.1f} s)",
                flush=True,
            )
        summary = {k: summarise(results, k) for k in INITS}
        runs.append(dict(name=name, cfg=cfg, summary=summary, results=results, timing=timing, warm=warm))
    report(a, runs, meta)


VERDICT = """## Verdict (seeds 100-111, this run)

- No gain from VoluMon initialisation in this setting. With texture planes ("main"), ROSHAN's own
  init starts closer (position 0.028 m against VoluMon's 0.092 m; 0.056 m with an exact input box)
  and stays closer up to the 5th detection (0.022 vs 0.036 m); by the end both agree within 2 mm
  (0.010 vs 0.012 m) and nothing collapses. The texture plane (1 cm + 1 % noise) measures depth
  better than the network infers it from a 7-25 px box at 128 x 96 px.
- Shape: the class-mean radii (section 4.3.4's table) are closer than VoluMon's sizes (0.008 vs
  0.013 m); orientation: the identity start is right for upright objects in a z-up world (32 deg:
  the yaw of the cracker boxes and balls; melons and cans are symmetric about z) while the network, trained on uniformly random orientations, has no
  upright prior (57 deg). Taking only VoluMon's centre ("VoluMon centre" rows) removes both
  penalties; what remains is the centre, which loses to the texture plane.
- Without texture planes ("boxes only") the network does not rescue ROSHAN either: its centre
  (0.092 m) is no better than the 1.0 m default depth (0.087 m) on objects first seen near 1.1 m,
  and about a fifth of the objects end more than 0.09 m off with every init (20-22 of 109).
- Beyond the training depth ("far", first detections at 1.1-1.5 m) VoluMon's depth saturates near
  1.2 m: 0.29 m initial error; boxes and texture planes repair it within 5 detections (0.032 m)
  and the end is equal (0.008 m).
- Also seen: the online smoother moves orientations away from the right identity start (32 to
  45-60 deg after 5-10 detections with every init): boxes of 7-25 px constrain a small object's yaw
  poorly and no factor says objects stand upright.
- VoluMon costs about 4 ms per new object here (one image, one box, the shipped CPU model).
"""

INITS = ("roshan", "volumon", "volumon_centre")
LABEL = {
    "roshan": "ROSHAN single-view init (4.3.5)",
    "volumon": "VoluMon init (6.3)",
    "volumon_centre": "VoluMon centre + identity rotation + class-mean radii",
}


def report(a, runs, meta):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxsem import scripting as sc

    date = subprocess.run(["date", "-u"], capture_output=True, text=True).stdout.strip()
    load = os.getloadavg()
    fmt = lambda v: f"{v[0]:.3f} / {v[1]:.3f} / {v[2]:.1f}"
    lines = [
        "# VoluMon-initialised ROSHAN vs ROSHAN's own initialisation (Forward, tabletop)",
        "",
        f"Command: `python benchmarks/roshan/roshan_volumon_init.py --maps {a.maps} --seed {a.seed} --frames {a.frames} "
        f"--optimize-every {a.optimize_every}`  ",
        f"Date: {date}; machine: 2-core CPU, shared, noisy (load average {load[0]:.1f}, {load[1]:.1f}, "
        f"{load[2]:.1f}); Python {platform.python_version()}, jax {jax.__version__}, float64; VoluMon model "
        f"`{meta.get('name')}` step {meta.get('step')}.  ",
        f"Maps: seeds {a.seed}-{a.seed + a.maps - 1}, not tuned on (the setting was chosen on seeds 0-1). "
        "Setting and protocol: the script's docstring.",
        "",
        "Cells: median over maps of each map's mean object error, position m / shape m / orientation deg"
        " (`jaxsem.metrics.ellipsoid_errors`); n = objects with at least k detections; k = 0 is the initial"
        f" ellipsoid itself. Collapsed: final position error > {COLLAPSE_M:.2f} m (the repo's 2 m rule of"
        f" `roshan_vs_quadricslam.py` scaled from its 30 m patch to this {PATCH} m one).",
    ]
    payload = {"ks": list(KS), "collapse_m": COLLAPSE_M, "variants": {}}
    for run in runs:
        results, summary, timing = run["results"], run["summary"], run["timing"]
        vt = 1e3 * np.median(timing["volumon_s"]) if timing["volumon_s"] else float("nan")
        rt = 1e3 * np.median(timing["render_s"]) if timing["render_s"] else float("nan")
        lines += [
            "",
            f"## {run['name']}: {VARIANT_NOTES[run['name']]}",
            "",
            f"{sum(r['objects'] for r in results)} observed objects on {len(results)} maps; "
            f"{sum(r['volumon_inits'] for r in results)} started from VoluMon (the others' rendered box was under "
            "2 px or the prediction invalid: ROSHAN's own init).",
            "",
            "| init | k = 0 (init) | after 1st det. | after 5th det. | end | collapsed objects | collapsed maps "
            "| objects > 2 m | ms/frame median (mean) |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for name in INITS:
            s = summary[name]
            e = s["end"]
            lines.append(
                f"| {LABEL[name]} | {fmt(s[0]['median'])} (n={s[0]['objects']}) | {fmt(s[1]['median'])} "
                f"(n={s[1]['objects']}) | {fmt(s[5]['median'])} (n={s[5]['objects']}) | {fmt(e['median'])} "
                f"(n={e['objects']}) | {e['collapsed_objects']} of {e['objects']} | {e['collapsed_maps']} of "
                f"{len(results)} | {e['over_2m']} | {e['ms_per_frame']:.1f} ({e['ms_per_frame_mean']:.1f}) |"
            )
        lines += [
            "",
            f"VoluMon: {vt:.1f} ms per new object (one image, one box; median after warm-up), not counted in "
            f"ms/frame; the stereo rendering ({rt:.1f} ms) stands in for the camera. The online update is one "
            f"compiled program for both inits. Warm-up map (compiles): {run['warm']:.0f} s.",
        ]
        payload["variants"][run["name"]] = {
            "note": VARIANT_NOTES[run["name"]],
            "summary": {n: {str(k): v for k, v in s.items()} for n, s in summary.items()},
            "maps": [
                {"seed": r["seed"], "objects": r["objects"], "volumon_inits": r["volumon_inits"]} for r in results
            ],
            "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(run["cfg"]).items()},
            "volumon_ms": vt,
            "render_ms": rt,
        }
    lines += ["", f"Figure: `{a.tag}.png` (error against the number of detections, every init and setting).", ""]
    if a.maps == 12 and a.seed == 100 and len(runs) == len(VARIANTS):
        lines += [VERDICT]
    text = "\n".join(lines)
    print(text)
    a.out.mkdir(parents=True, exist_ok=True)
    sc.atomic_write_text(a.out / f"{a.tag}.md", text)
    sc.atomic_write_text(a.out / f"{a.tag}.json", json.dumps(payload, indent=1, default=float))
    fig, axes = plt.subplots(len(runs), 3, figsize=(12, 3.2 * len(runs)), squeeze=False)
    for row, run in zip(axes, runs):
        for name, colour in zip(INITS, ("tab:blue", "tab:orange", "tab:green")):
            s = run["summary"][name]
            for q, ax in enumerate(row):
                ax.plot(KS, [s[k]["median"][q] for k in KS], "o-", color=colour, label=LABEL[name], ms=3)
                ax.axhline(s["end"]["median"][q], color=colour, ls="--", lw=1)
        for ax, t in zip(row, ("position (m)", "shape (m)", "orientation (deg)")):
            ax.set_ylabel(t)
            ax.grid(alpha=0.3)
            ax.set_title(run["name"], fontsize=9)
    for ax in axes[-1]:
        ax.set_xlabel("detections of the object (0 = initial ellipsoid)")
    fig.suptitle(
        f"Median map error vs detections, Forward tabletop, {a.maps} maps (seeds {a.seed}+); dashed: end",
        fontsize=10,
    )
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=8)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    sc.atomic_savefig(fig, a.out / f"{a.tag}.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
