"""The integration experiment (thesis 5.8.3, issue 13 part 3), ground-truth object maps first.

On unseen (test-family) buildings, the online loop of jaxsem.planning runs, from the same start,
yaw and PRNG key, with:

- ``uniform``: the uniform PRM (Euclidean edges), the thesis' PRM + Unf;
- ``lsd``: LSD fed the robot's own object-camera semantic cells (chapter 3 as shipped);
- ``lsd_objmap``: LSD fed an object map (jaxsem.mapping) built online from the ground-truth
  ellipsoids of every door, window and exit sign the object camera has seen so far (one
  ``mapping.update`` per replan), rasterised as ellipse footprints: the 5.8.3 pipeline with a
  perfect estimator in place of VoluMon / ROSHAN;
- ``lsd_prior``: LSD fed the object map of *all* the building's objects from the start (an
  oracle: what a complete, exact object map would buy);
- ``lsd_depthmap``: LSD fed an object map of *estimated* objects: every ``--observe-every``
  steps the robot's camera view is rendered (jaxsem.mapping.BuildingRenderer at the robot's pose),
  door / window / exit-sign boxes are read off the segmentation (the stand-in detector), and
  each detected object's segmented depth pixels give a per-frame ellipsoid
  (``jaxsem.mapping.ellipsoids_from_depth``: a depth stand-in for VoluMon), associated (greedy by
  centroid) and fused into a jaxsem.mapping store;
- ``lsd_volumon``: the same rendered views and detections as ``lsd_depthmap``, but each door's
  ellipsoid is the shipped VoluMon door model's single-view estimate from the RGB image and its
  box (``jaxsem.volumon.load_pretrained(kind="door")``, thesis 5.8.1-5.8.2; monocular, no depth);
  windows and exit signs, which the door model does not cover, keep the depth stand-in;
- ``lsd_roshan``: LSD fed ROSHAN's object map: the same boxes, with the known camera poses, the
  renderer's object index as association id and the object's nearest depth as texture plane,
  go into ROSHAN's online smoother (jaxsem.slam, via jaxsem.mapping.roshan_init / roshan_frame);
  its current ellipsoids (jaxsem.mapping.roshan_objects) are the map at each replan.

Rows (b) and (c) are rasterised by the same jaxsem.mapping.semantic_grid path as
``lsd_objmap``, and their object-map error (jaxsem.mapping.map_errors: position and size error
of each seen object's nearest same-class map object, jaxsem.metrics.ellipsoid_errors) is
recorded at trial end.

Success rate per sample budget N and, on trials where every planner succeeded, C/C* (metres
travelled over the resolution-optimal length) as mean +- s.e.m. (Table 3.1's statistic).
Writes benchmarks/results/pipeline.{json,md}.

    python benchmarks/pipeline.py                   # small CPU run (bundled LSD model)
    python benchmarks/pipeline.py --test-buildings 4 --trials 5 --n 100 500 1000 --max-steps 2000
    python benchmarks/pipeline.py --planners uniform lsd_objmap lsd_depthmap   # a subset
"""

from __future__ import annotations

import argparse
import pathlib
import platform
import sys
import time

import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _harness

RESULTS = pathlib.Path(__file__).resolve().parent / "results"
PLANNERS = ("uniform", "lsd", "lsd_objmap", "lsd_prior", "lsd_depthmap", "lsd_volumon", "lsd_roshan")
ESTIMATED = ("lsd_depthmap", "lsd_volumon", "lsd_roshan")
KINDS = {"lsd_depthmap": "depth", "lsd_volumon": "volumon", "lsd_roshan": "roshan"}
WIDTH, HEIGHT = 320, 240  # robot camera image (69.4 deg horizontal field of view, 1.2 m up)


class DetectionMapper:
    """An object map built online from rendered detections (rows ``lsd_depthmap``,
    ``lsd_volumon`` and ``lsd_roshan``).

    ``observe(xy, yaw)`` renders the robot camera's view, detects doors, windows and exit signs
    (segmentation boxes of at least ``min_area`` pixels) and feeds them to the estimator:
    ``"depth"``: per-frame ellipsoids from depth (boxes touching the image border are left out:
    their depth extent is cut), ``mapping.update`` with centroid gate ``gate``; ``"volumon"``:
    the same, but doors from ``estimator`` (a ``jaxsem.volumon.SingleViewEstimator``: RGB + box
    -> world ellipsoid), windows and exit signs from depth; ``"roshan"``:
    one ROSHAN frame. ``objects()`` is the current map; ``errors()`` its error against the
    ground-truth ellipsoids of the objects detected so far.
    """

    def __init__(
        self,
        renderer,
        objects,
        capacity,
        kind,
        *,
        min_area=100,
        gate=0.75,
        fusion="latest",
        texture=True,
        estimator=None,
    ):
        from jaxsem import mapping, slam
        from jaxsem.mapping import robot_intrinsics
        from jaxsem.planning import DOOR, EXIT_SIGN, WINDOW

        if kind not in ("depth", "volumon", "roshan"):
            raise ValueError(f"kind: expected 'depth', 'volumon' or 'roshan', got {kind!r}")
        if kind == "volumon" and estimator is None:
            raise ValueError("estimator: kind 'volumon' needs a jaxsem.volumon.SingleViewEstimator")
        self.estimator = estimator
        self.renderer, self.kind, self.min_area = renderer, kind, int(min_area)
        self.gate, self.fusion, self.texture = float(gate), fusion, bool(texture)
        self.classes = (DOOR, WINDOW, EXIT_SIGN)
        self.object_class = objects.class_id
        self.truth = objects.ellipsoids(capacity)
        self.K = robot_intrinsics(WIDTH, HEIGHT)
        self.seen = np.zeros(capacity, bool)
        self.frames = 0
        self.door_estimates = 0
        self.max_det = 16
        if kind in ("depth", "volumon"):
            self.store = mapping.init(capacity)
        else:
            cap = slam.Capacity(max_poses=64, max_objects=capacity, max_boxes=512, max_detections=self.max_det)
            self.state = mapping.roshan_init(self.K, (WIDTH, HEIGHT), cap)
        self._objects = None

    def observe(self, xy, yaw):
        from jaxsem import mapping, quadrics, slam
        from jaxsem.mapping import ellipsoids_from_depth, robot_camera

        T = robot_camera(np.asarray(xy, float), float(yaw))
        passes = ("rgb", "depth", "seg") if self.kind == "volumon" else ("depth", "seg")
        out = self.renderer.render(self.K, T, outputs=passes)
        seg, depth = out["seg"], out["depth"]
        det = self.renderer.detect(seg, self.classes, min_area=self.min_area)
        if len(det) == 0:
            return
        if len(det) > self.max_det:  # the largest boxes first
            keep = np.argsort(-det.area)[: self.max_det]
            det = type(det)(det.box[keep], det.class_id[keep], det.object_index[keep], det.area[keep])
        self.seen[det.object_index] = True
        self.frames += 1
        self._objects = None
        if self.kind in ("depth", "volumon"):
            inside = (
                (det.box[:, 0] > 0) & (det.box[:, 1] > 0) & (det.box[:, 2] < WIDTH - 1) & (det.box[:, 3] < HEIGHT - 1)
            )
            wanted = det.object_index[inside]
            if len(wanted) == 0:
                return
            n_vis = len(np.unique(seg[seg >= 0]))
            slots = max(self.max_det, int(2 ** np.ceil(np.log2(max(n_vis, 1)))))  # few compiles
            ell, idx = ellipsoids_from_depth(
                seg, depth, quadrics.Camera(self.K, T), self.object_class, self.classes, capacity=slots
            )
            valid = np.zeros(ell.valid.shape[0], bool)
            valid[: len(idx)] = np.isin(idx, wanted)
            if self.kind == "volumon":
                ell, valid = self._doors_from_volumon(out["rgb"], det, inside, T, ell, idx, valid)
            ell = mapping.Ellipsoids(ell.rotation, ell.center, ell.radii, ell.class_id, ell.valid & valid)
            self.store = mapping.update(self.store, ell, gate=self.gate, fusion=self.fusion)
        else:
            tex = np.full(len(det), np.nan)
            if self.texture:  # the object's near surface: a low percentile of its depth pixels
                for i, k in enumerate(det.object_index):
                    d = depth[(seg == k) & (depth > 0)]
                    if d.size:
                        tex[i] = np.percentile(d, 5)
            frame = mapping.roshan_frame(
                T, det.box, det.class_id, det.object_index, tex, max_detections=self.max_det, image_size=(WIDTH, HEIGHT)
            )
            self.state = slam.online_update(self.state, frame)

    def _doors_from_volumon(self, rgb, det, inside, T, ell, idx, valid):
        """Replace the depth estimates of the detected doors by the door model's (RGB + box)."""
        from jaxsem import mapping
        from jaxsem.planning import DOOR

        doors = inside & (det.class_id == DOOR)
        R, c, r = self.estimator(rgb, det.box[doors], self.K, T)
        rot, cen, rad = (np.array(a, np.float64) for a in (ell.rotation, ell.center, ell.radii))
        cls, valid = np.array(ell.class_id), valid.copy()
        valid[: len(idx)] &= ~np.isin(idx, det.object_index[doors])  # doors: not from depth
        free = np.flatnonzero(~valid)[: len(c)]  # slots for the door estimates
        rot[free], cen[free], rad[free], cls[free] = R[: len(free)], c[: len(free)], r[: len(free)], DOOR
        valid[free] = True
        self.door_estimates += len(free)
        dt = ell.center.dtype
        ell = mapping.Ellipsoids(
            jnp.asarray(rot, dt), jnp.asarray(cen, dt), jnp.asarray(rad, dt), jnp.asarray(cls), jnp.asarray(valid)
        )
        return ell, valid

    def objects(self):
        from jaxsem import mapping

        if self._objects is None:
            self._objects = self.store if self.kind in ("depth", "volumon") else mapping.roshan_objects(self.state)
        return self._objects

    def errors(self) -> dict:
        from jaxsem import mapping

        truth = self.truth
        truth = mapping.Ellipsoids(truth.rotation, truth.center, truth.radii, truth.class_id, truth.valid & self.seen)
        e = mapping.map_errors(self.objects(), truth)
        seen = np.asarray(truth.valid)
        pos, shape = e["position"][seen], e["shape"][seen]
        return {
            "seen": int(seen.sum()),
            "matched": int(e["matched"][seen].sum()),
            "frames": self.frames,
            "door_estimates": self.door_estimates,
            "position": [float(v) for v in pos],
            "shape": [float(v) for v in shape],
            "class_id": [int(v) for v in np.asarray(truth.class_id)[seen]],
        }


class ObjectMapSampler:
    """LSD sampler whose semantic crop comes from an object map of a trial's seen objects.

    ``bind(trial)`` after the trial is built; at each replan the ground-truth ellipsoids of the
    objects with a cell in the trial's semantic map go into the store as one frame. With a
    ``mapper`` (a :class:`DetectionMapper`) the map is the mapper's current objects instead.
    """

    def __init__(self, lsd, building, objects, capacity, prior: bool, mapper=None):
        from jaxsem import mapping

        self.lsd, self.building, self.prior, self.mapper = lsd, building, prior, mapper
        self.dets = objects.ellipsoids(capacity)
        self.cells = objects.cells
        self.state = mapping.init(capacity)
        self.trial = None
        self.calls = 0
        if prior:
            self.state = mapping.update(self.state, self.dets, gate=0.5)

    def bind(self, trial):
        self.trial = trial

    def __call__(self, inputs):
        from jaxsem import mapping

        b = self.building
        if self.mapper is not None:
            self.state = self.mapper.objects()
        elif not self.prior:
            assert self.trial is not None, "bind(trial) first"
            sem = np.asarray(self.trial.state.semantic)
            seen = np.array(
                [np.any(sem[r0:r1, c0:c1] > 0) for r0, c0, r1, c1 in self.cells]
                + [False] * (self.dets.valid.shape[0] - len(self.cells))
            )
            frame = mapping.Ellipsoids(
                self.dets.rotation,
                self.dets.center,
                self.dets.radii,
                self.dets.class_id,
                self.dets.valid & seen,
            )
            self.state = mapping.update(self.state, frame, gate=0.5)
        try:
            grid = mapping.semantic_grid(self.state, b.grid)
        except ValueError:  # an estimate too large for the tiles (a diverged one): draw it whole
            grid = mapping.semantic_grid(self.state, b.grid, window=None)
        self.calls += 1
        return mapping.object_map_sampler(self.lsd, grid)(inputs)


def run(args) -> dict:
    from jaxsem import mapping
    from jaxsem.lsd import LSDSampler, load_model
    from jaxsem.lsd._experiment import nav_record, trial_key  # layers: white-box
    from jaxsem.mapping import BuildingRenderer
    from jaxsem.metrics import mean_sem
    from jaxsem.planning import DOOR, NavConfig, Trial, sample_tasks
    from jaxsem.planning._buildings import building_family  # layers: white-box

    planners = tuple(args.planners)
    model, params, _, _ = load_model(args.checkpoint)
    lsd = LSDSampler(model, params, uniform_mix=args.uniform_mix)
    buildings = building_family("test", args.test_buildings, start=args.test_start)
    estimator = None
    if "lsd_volumon" in planners:
        from jaxsem.volumon import SingleViewEstimator, load_pretrained

        door_model, door_vars, door_cfg, _ = load_pretrained(args.door_model, kind="door")
        estimator = SingleViewEstimator(door_model, door_vars, door_cfg)
    records = []
    for b in buildings:
        objects = mapping.building_objects(b)
        capacity = int(2 ** np.ceil(np.log2(max(len(objects), 1))))  # one compile per bucket
        renderer = BuildingRenderer(b, WIDTH, HEIGHT) if any(p in ESTIMATED for p in planners) else None
        for kind in args.sets:
            for t_i, task in enumerate(sample_tasks(b, kind, args.trials, args.seed)):
                for n in args.n:
                    key = trial_key(args.seed, b.seed, kind, t_i, n)
                    rec = {
                        "building": int(b.seed),
                        "set": kind,
                        "trial": t_i,
                        "n": int(n),
                        "c_star": float(task.c_star),
                        "objects": len(objects),
                    }
                    for name in planners:
                        sampler, mapper = None, None
                        if name == "lsd":
                            sampler = lsd
                        elif name in ("lsd_objmap", "lsd_prior"):
                            sampler = ObjectMapSampler(lsd, b, objects, capacity, name == "lsd_prior")
                        elif name in ESTIMATED:
                            mapper = DetectionMapper(
                                renderer,
                                objects,
                                capacity,
                                KINDS[name],
                                min_area=args.min_area,
                                fusion=args.fusion,
                                texture=not args.no_texture,
                                estimator=estimator,
                            )
                            sampler = ObjectMapSampler(lsd, b, objects, capacity, False, mapper)
                        cfg = NavConfig(n_samples=int(n), max_steps=args.max_steps)
                        t0 = time.perf_counter()
                        trial = Trial(
                            b,
                            task.start,
                            task.goal,
                            key,
                            cfg,
                            sampler,
                            yaw0=task.yaw0,
                            goal_outdoors=task.goal_outdoors,
                        )
                        if isinstance(sampler, ObjectMapSampler):
                            sampler.bind(trial)
                        if mapper is not None:
                            mapper.observe(trial.xy, trial.yaw)  # the first plan sees the start view
                        while trial.step():
                            if mapper is not None and trial.steps % args.observe_every == 0:
                                mapper.observe(trial.xy, trial.yaw)
                        rec[name] = nav_record(trial.result(), time.perf_counter() - t0)
                        if isinstance(sampler, ObjectMapSampler):
                            rec[name]["mapped_objects"] = int(np.asarray(sampler.state.valid).sum())
                        if mapper is not None:
                            rec[name]["map_error"] = mapper.errors()
                    records.append(rec)
                    if not args.no_progress:
                        print(
                            f"building {b.seed} {kind} trial {t_i} N={n}: "
                            + ", ".join(
                                f"{p} {'ok' if rec[p]['success'] else 'fail'} {rec[p]['cost']:.1f} m ({rec[p]['seconds']:.0f} s)"
                                for p in planners
                            ),
                            flush=True,
                        )
        if renderer is not None:
            renderer.close()
    summary = {}
    for kind in args.sets:
        for n in args.n:
            rs = [r for r in records if r["set"] == kind and r["n"] == n]
            mutual = [r for r in rs if all(r[p]["success"] for p in planners)]
            row = {"set": kind, "n": int(n), "trials": len(rs), "mutual": len(mutual)}
            for p in planners:
                row[f"success_{p}"] = float(np.mean([r[p]["success"] for r in rs])) if rs else float("nan")
                row[f"ratio_{p}"] = mean_sem([r[p]["cost"] / r["c_star"] for r in mutual])
                if p in ESTIMATED:  # pooled over the seen objects of every trial of the row
                    errs = [r[p]["map_error"] for r in rs]
                    pos = [v for e in errs for v in e["position"] if np.isfinite(v)]
                    shp = [v for e in errs for v in e["shape"] if np.isfinite(v)]
                    door = [  # (position, size) of the doors alone (the class the door model covers)
                        (pv, sv)
                        for e in errs
                        for pv, sv, c in zip(e["position"], e["shape"], e.get("class_id", []))
                        if c == DOOR and np.isfinite(pv)
                    ]
                    row[f"map_{p}"] = {
                        "seen": int(sum(e["seen"] for e in errs)),
                        "matched": int(sum(e["matched"] for e in errs)),
                        "position_median": float(np.median(pos)) if pos else float("nan"),
                        "shape_median": float(np.median(shp)) if shp else float("nan"),
                        "doors_matched": len(door),
                        "door_position_median": float(np.median([d[0] for d in door])) if door else float("nan"),
                        "door_shape_median": float(np.median([d[1] for d in door])) if door else float("nan"),
                    }
            summary[f"{kind}-{n}"] = row
    return {"summary": summary, "records": records}


def _planners(summary: dict) -> list:
    row = next(iter(summary.values()), {})
    return [p for p in PLANNERS if f"success_{p}" in row]


def format_table(summary: dict) -> str:
    def pm(ms):
        m, s = ms
        return "-" if not np.isfinite(m) else f"{m:.2f} +- {s:.2f}"

    planners = _planners(summary)
    head = ["set", "N", "trials", "mutual"] + [f"success {p}" for p in planners] + [f"C/C* {p}" for p in planners]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in summary.values():
        cells = [row["set"], str(row["n"]), str(row["trials"]), str(row["mutual"])]
        cells += [f"{100 * row[f'success_{p}']:.0f} %" for p in planners]
        cells += [pm(row[f"ratio_{p}"]) for p in planners]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_map_table(summary: dict) -> str:
    """Object-map error of the estimated rows: medians over the seen objects of a row's trials."""
    planners = [p for p in _planners(summary) if p in ESTIMATED]
    if not planners:
        return ""
    head = [
        "set",
        "N",
        "map",
        "objects seen",
        "matched (2 m gate)",
        "position error (m, median)",
        "size error (m, median)",
        "doors matched",
        "door position error (m, median)",
        "door size error (m, median)",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in summary.values():
        for p in planners:
            m = row[f"map_{p}"]
            f = lambda v: "-" if not np.isfinite(v) else f"{v:.2f}"
            cells = [row["set"], str(row["n"]), p, str(m["seen"]), str(m["matched"])]
            cells += [f(m["position_median"]), f(m["shape_median"])]
            cells += [str(m.get("doors_matched", "-")), f(m.get("door_position_median", np.nan))]
            cells += [f(m.get("door_shape_median", np.nan))]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "pipeline").splitlines()[0])
    p.add_argument("--checkpoint", default=None, help="LSD model (default: the bundled CPU model)")
    p.add_argument("--test-buildings", type=int, default=2)
    p.add_argument("--test-start", type=int, default=0)
    p.add_argument("--trials", type=int, default=2, help="tasks per building and set")
    p.add_argument("--n", type=int, nargs="+", default=[500])
    p.add_argument("--sets", nargs="+", default=["IO", "II"])
    p.add_argument("--max-steps", type=int, default=600)
    p.add_argument("--uniform-mix", type=float, default=0.1)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=str(RESULTS))
    p.add_argument("--name", default="pipeline")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--planners", nargs="+", default=list(PLANNERS), choices=PLANNERS)
    p.add_argument("--observe-every", type=int, default=5, help="steps between rendered views (estimated maps)")
    p.add_argument("--min-area", type=int, default=100, help="fewest segmented pixels of a detection box")
    p.add_argument("--fusion", default="latest", choices=("latest", "mean"), help="lsd_depthmap store fusion")
    p.add_argument("--no-texture", action="store_true", help="lsd_roshan without depth texture planes")
    p.add_argument(
        "--door-model",
        default=None,
        help="lsd_volumon's door model: a training workdir or .npz (default: the shipped volumon_door)",
    )
    args = p.parse_args(argv)
    if args.observe_every < 1:
        p.error(f"--observe-every: expected >= 1, got {args.observe_every}")
    try:
        from jaxsem.cli import enable_compilation_cache

        enable_compilation_cache()
    except ImportError:  # pragma: no cover - older checkouts
        pass
    t0 = time.perf_counter()
    result = run(args)
    total = time.perf_counter() - t0
    table = format_table(result["summary"])
    map_table = format_map_table(result["summary"])
    print(table)
    print(map_table)
    cmd = " ".join(["python benchmarks/pipeline.py", *(sys.argv[1:] if argv is None else argv)])
    date = _harness.utc_now()
    machine = f"{platform.machine()} CPU, {_harness.nproc()} cores (shared, noisy)"
    record = {"command": cmd, "date": date, "machine": machine, "args": vars(args), "seconds": total, **result}
    md = [
        *_harness.header(f"## Integration: LSD with object maps (`{args.name}`, thesis 5.8.3)", cmd, date, machine),
        (
            f"Test-family buildings {args.test_start}..{args.test_start + args.test_buildings - 1}, "
            f"{args.trials} tasks per building and set, step limit {args.max_steps}, LSD uniform mix "
            f"{args.uniform_mix}, bundled CPU LSD model; total {total / 60:.1f} min. Planners: "
            "`uniform` PRM; `lsd` with its own object-camera cells; `lsd_objmap` with a jaxsem.mapping "
            "object map of the ground-truth ellipsoids of the objects seen so far (ellipse "
            "footprints); `lsd_prior` with every object of the building mapped from the start; "
            "`lsd_depthmap` and `lsd_roshan` with object maps of *estimated* objects from the robot "
            f"camera's rendered views ({WIDTH} x {HEIGHT} px, every {args.observe_every} steps; "
            f"door / window / exit-sign boxes of at least {args.min_area} px from the segmentation): "
            "`lsd_depthmap` per-frame ellipsoids from the segmented depth "
            "(`jaxsem.mapping.ellipsoids_from_depth`, a depth stand-in for VoluMon; boxes touching the "
            f"border left out), greedy centroid association, fusion `{args.fusion}`; `lsd_volumon` "
            "the same, but every door's ellipsoid from the shipped VoluMon door model (RGB image + "
            "box, monocular; `jaxsem.volumon.load_pretrained(kind='door')`), windows and exit signs "
            "(not covered by the door model) still from depth; `lsd_roshan` ROSHAN's online smoother "
            "fed the same boxes with the known "
            "camera poses and the renderer's association"
            + ("" if args.no_texture else ", texture plane at the 5th percentile of the object's depth")
            + ". C/C* on trials where every planner succeeded."
        ),
        "",
        table,
        "",
        "Object-map error at trial end (each seen object's nearest same-class map object within "
        "2 m, `jaxsem.mapping.map_errors`; size error is the norm of the sorted radii difference):",
        "",
        map_table,
        "",
        (
            "Read small runs as smoke tests: with a handful of trials per row and one mutual "
            "success the s.e.m. is 0 by construction. C* is the length of the soft-cost "
            "optimal path (it keeps away from walls), so C/C* slightly below 1 is possible."
        ),
        "",
    ]
    out = _harness.write_results(args.out, args.name, record, md, json_default=float)
    print(f"wrote {out / (args.name + '.json')} and .md in {total / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
