"""The ROSHAN glue: the demo part, the sequence-directory layout of infer/roshan.py, bad input."""

import pathlib
import re

import numpy as np
import pytest

from jaxsem.slam._map_json import truth_errors  # layers: white-box
from jaxsem.slam._sequence import sequence_from_simulation  # layers: white-box
from jaxsem.slam._solver_config import NoiseModel  # layers: white-box


def _table_rows(table: str) -> dict:
    rows = {}
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 4 and cells[0] in ("baseline", "roshan"):
            rows[cells[0]] = [float(c) for c in cells[1:4]]
    return rows


@pytest.mark.slow
def test_quick_demo_writes_figure_and_table(tmp_path: pathlib.Path):
    from jaxsem.demos import roshan

    table = roshan.run(tmp_path, quick=True)
    png = tmp_path / "roshan_forward.png"
    assert png.exists() and png.stat().st_size > 10_000
    rows = _table_rows(table)
    assert set(rows) == {"baseline", "roshan"}
    assert all(np.isfinite(v).all() for v in rows.values())
    # Forward flight, fixed seed: ROSHAN's texture planes and shape prior fix the depth the
    # boxes alone leave open (true on every seed tried in float32 and float64).
    assert rows["roshan"][1] < rows["baseline"][1]
    assert re.search(r"\| shape \(m\) \| position \(m\) \| orientation \(deg\)", table)


# --------------------------------------------------------------------------------------------
# Sequence directories (infer/roshan.py).

SIZES = dict(num_objects=4, num_frames=30, forward_step=0.75 * 59 / 29)


@pytest.fixture(scope="module")
def simulated():
    import jax

    from jaxsem.slam import sim

    cfg = sim.quadricslam_config("forward", **SIZES)
    one = jax.jit(sim.simulate, static_argnums=1)(jax.random.key(2), cfg)
    return cfg, one, sequence_from_simulation(one, cfg.image_size)


@pytest.mark.slow
def test_sequence_round_trip_and_online_map_close_to_truth(tmp_path, simulated):
    import json

    from jaxsem import slam
    from jaxsem.slam import sim

    cfg, one, seq = simulated
    slam.save_sequence(seq, tmp_path / "seq")
    back = slam.load_sequence(tmp_path / "seq")
    assert back.image_size == (640, 480) and len(back.frames) == cfg.num_frames
    np.testing.assert_allclose(back.K, seq.K)
    for a, b in zip(seq.frames, back.frames):
        np.testing.assert_allclose(b.camera_T_world, a.camera_T_world)
        np.testing.assert_allclose(b.boxes, a.boxes)
        np.testing.assert_array_equal(np.isnan(b.texture_depth), np.isnan(a.texture_depth))
        np.testing.assert_allclose(
            b.texture_depth[~np.isnan(b.texture_depth)],
            a.texture_depth[~np.isnan(a.texture_depth)],
        )
        assert b.ids == a.ids and b.classes == a.classes
    assert back.object_ids == seq.object_ids
    assert [o["id"] for o in back.truth["objects"]] == [o["id"] for o in seq.truth["objects"]]
    # Detections = the simulator's (ground-truth association, noisy odometry poses).
    mask = np.asarray(one.box_mask)
    assert sum(len(f.ids) for f in back.frames) == int(mask.sum())
    t, j = np.argwhere(mask)[0]
    k = back.frames[t].ids.index(int(j))
    np.testing.assert_allclose(back.frames[t].boxes[k], np.asarray(one.boxes[t, j]))
    np.testing.assert_allclose(back.frames[t].camera_T_world, np.asarray(one.pose_prior[t]))

    frames_seen = []
    result = slam.run_sequence(
        back,
        sim.solver_config(sim.ROSHAN, cfg),
        optimize_every=5,
        iterations=3,
        final_iterations=10,
        callback=lambda i, s, dt: frames_seen.append(i),
    )
    assert frames_seen == list(range(cfg.num_frames))
    out = json.loads(
        json.dumps(
            slam.map_to_json(
                result.object_ids,
                result.object_classes,
                result.ellipsoid,
                result.camera_T_world,
            )
        )
    )
    assert [o["id"] for o in out["objects"]] == list(back.object_ids)
    truth = {o["id"]: o for o in back.truth["objects"]}
    err = [np.linalg.norm(np.array(o["center"]) - truth[o["id"]]["center"]) for o in out["objects"]]
    assert np.median(err) < 1.0 and max(err) < 2.5, err
    for o in out["objects"]:
        assert o["class"] == "car" and min(o["radii"]) > 0
        R = np.array(o["rotation"])
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-6)
    assert np.all(np.isfinite(np.array(out["camera_T_world"])))
    e = truth_errors(result, back.truth)
    np.testing.assert_allclose(np.sort(e["position"]), np.sort(err), atol=1e-9)


@pytest.mark.slow
def test_infer_script_writes_map_and_figures(tmp_path, simulated):
    import importlib.util
    import json

    spec = importlib.util.spec_from_file_location(
        "infer_roshan", pathlib.Path(__file__).parents[2] / "infer" / "roshan.py"
    )
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    cfg, _, seq = simulated
    from jaxsem import slam

    out = tmp_path / "out"
    # The fixture's map again (same seed and sizes), so the online solver's compilation is reused.
    assert (
        script.main(
            [
                "--simulate",
                "forward",
                "--seed",
                "2",
                "--objects",
                "4",
                "--frames",
                "30",
                "--write-sequence",
                str(tmp_path / "seq"),
                "--out",
                str(out),
                "--overlays",
                "2",
                "--final-iterations",
                "10",
                "--quiet",
            ]
        )
        == 0
    )
    written = slam.load_sequence(tmp_path / "seq")
    assert written.object_ids == seq.object_ids
    np.testing.assert_allclose(
        np.stack([f.camera_T_world for f in written.frames]),
        np.stack([f.camera_T_world for f in seq.frames]),
    )
    data = json.loads((out / "map.json").read_text())
    assert len(data["objects"]) == len(seq.object_ids)
    assert (out / "top_down.png").stat().st_size > 10_000
    overlays = sorted(out.glob("overlay_*.png"))
    assert [p.name for p in overlays] == [
        "overlay_000000.png",
        f"overlay_{cfg.num_frames - 1:06d}.png",
    ]


def _write(tmp_path, data, name="sequence.json"):
    import json

    d = tmp_path / "bad"
    d.mkdir(exist_ok=True)
    (d / name).write_text(data if isinstance(data, str) else json.dumps(data))
    return d


def _good():
    return {
        "K": [[500.0, 0, 320], [0, 500, 240], [0, 0, 1]],
        "image_size": [640, 480],
        "frames": [
            {
                "camera_T_world": np.eye(4).tolist(),
                "detections": [
                    {
                        "box": [10, 20, 50, 60],
                        "class": "car",
                        "id": 0,
                        "texture_depth": 9.0,
                    },
                    {"box": [100, 20, 150, 60], "class": "person", "id": "p1"},
                ],
            }
        ],
    }


def test_sequence_bad_input_names_file_and_field(tmp_path):
    from jaxsem import slam

    seq = slam.load_sequence(_write(tmp_path, _good()))  # the good one loads
    assert seq.object_ids == (0, "p1") and seq.object_classes == ("car", "person")
    assert np.isnan(seq.frames[0].texture_depth[1])

    with pytest.raises(ValueError, match=r"nowhere.*no such file"):
        slam.load_sequence(tmp_path / "nowhere")
    with pytest.raises(ValueError, match=r"sequence\.json: malformed JSON at line 1"):
        slam.load_sequence(_write(tmp_path, "{not json"))

    def bad(edit, pattern):
        data = _good()
        edit(data)
        with pytest.raises(ValueError, match=pattern):
            slam.load_sequence(_write(tmp_path, data))

    det = lambda d: d["frames"][0]["detections"]
    bad(
        lambda d: det(d)[1].update({"class": "unicorn"}),
        r"sequence\.json: frames\[0\]\.detections\[1\]\.class: unknown class 'unicorn'",
    )
    bad(
        lambda d: det(d)[0].update({"box": [50, 20, 10, 60]}),
        r"frames\[0\]\.detections\[0\]\.box",
    )
    bad(
        lambda d: det(d)[0].update({"box": [1, 2, 3]}),
        r"frames\[0\]\.detections\[0\]\.box",
    )
    bad(
        lambda d: det(d)[0].update({"box": [700, 20, 800, 60]}),
        r"detections\[0\]\.box: .*outside",
    )
    bad(
        lambda d: det(d)[0].update({"texture_depth": -1}),
        r"detections\[0\]\.texture_depth",
    )
    bad(lambda d: det(d)[0].pop("id"), r"detections\[0\]\.id: missing")
    bad(
        lambda d: det(d)[1].update({"id": 0}),
        r"frames\[0\]\.detections: an association id appears twice",
    )
    bad(lambda d: d.pop("K"), r"sequence\.json: K: missing")
    bad(lambda d: d.update({"image_size": [640]}), r"image_size")
    bad(
        lambda d: d["frames"][0].update({"camera_T_world": [[1, 0], [0, 1]]}),
        r"frames\[0\]\.camera_T_world",
    )
    bad(
        lambda d: d["frames"][0].update({"image": "missing.png"}),
        r"frames\[0\]\.image: .*missing\.png.*does not exist",
    )
    bad(lambda d: d.update({"frames": []}), r"frames: expected a non-empty list")
    # issue 26 item 6: no detection at all (a misspelt key), a box far larger than the image
    bad(
        lambda d: d["frames"][0].update({"detection": d["frames"][0].pop("detections")}),
        r"sequence\.json: frames\[\*\]\.detections: no frame has any detection.*keys seen: \['camera_T_world', 'detection'\]",
    )
    bad(lambda d: d["frames"][0].update({"detections": []}), r"no frame has any detection")
    bad(lambda d: det(d)[0].update({"box": [0, 0, 1e9, 1e9]}), r"detections\[0\]\.box: .*over 10 times the 640x480")


def test_sequence_noise_model_loads_validates_and_round_trips(tmp_path):
    import math

    from jaxsem import slam

    data = _good()
    data["noise"] = {"box_sigma": 2.0, "pose_rotation_sigma_deg": 2.0}
    seq = slam.load_sequence(_write(tmp_path, data))
    noise = slam.noise_model(seq)
    assert noise.box_sigma == 2.0 and math.isclose(noise.pose_rotation_sigma, math.radians(2.0))
    assert noise.texture_sigma == NoiseModel().texture_sigma  # untouched fields keep defaults
    slam.save_sequence(seq, tmp_path / "rt")
    assert slam.load_sequence(tmp_path / "rt").noise == seq.noise
    for noise_field, pattern in (
        ({"box_sigma": -1}, r"noise\.box_sigma: expected a finite number > 0"),
        ({"bogus": 1.0}, r"noise\.bogus: unknown field"),
        ([1, 2], r"sequence\.json: noise: expected an object"),
    ):
        data["noise"] = noise_field
        with pytest.raises(ValueError, match=pattern):
            slam.load_sequence(_write(tmp_path, data))


@pytest.mark.slow
def test_sequence_initial_ellipsoids_load_validate_and_are_used(tmp_path):
    from jaxsem import slam

    data = _good()
    given = {"center": [0.3, -0.2, 12.0], "radii": [2.1, 0.9, 0.8], "rotation": np.eye(3).tolist()}
    data["initial"] = [{"id": 0, **given}]
    seq = slam.load_sequence(_write(tmp_path, data))
    np.testing.assert_allclose(seq.initial[0]["center"], given["center"])
    slam.save_sequence(seq, tmp_path / "rt")
    back = slam.load_sequence(tmp_path / "rt")
    np.testing.assert_allclose(back.initial[0]["radii"], given["radii"])
    # No optimisation runs (one frame, optimize_every 5, no final steps): object 0 holds exactly
    # the given values, object "p1" its single-view initialisation from the box.
    res = slam.run_sequence(seq, optimize_every=5, iterations=1, final_iterations=0)
    np.testing.assert_allclose(res.center[0], given["center"], atol=1e-5)
    np.testing.assert_allclose(res.radii[0], given["radii"], atol=1e-5)
    # the same settings as res (iterations=1 too: no optimisation runs either way), so the
    # online program compiled for res serves this run
    plain = slam.run_sequence(
        slam.load_sequence(_write(tmp_path, _good())), optimize_every=5, iterations=1, final_iterations=0
    )
    assert np.linalg.norm(plain.center[0] - np.asarray(given["center"])) > 0.1
    np.testing.assert_allclose(res.center[1], plain.center[1], atol=1e-6)
    for initial, pattern in (
        ([{"id": 7, **given}], r"initial\[0\]\.id: id 7 is never detected"),
        ([{"id": 0, **{**given, "radii": [1, -1, 1]}}], r"initial\[0\]\.radii: expected 3 finite positive"),
        ([{"id": 0, "center": [0, 0, 1], "radii": [1, 1, 1]}], r"initial\[0\]\.rotation: missing"),
        ({"id": 0}, r"initial: expected a list"),
    ):
        data["initial"] = initial
        with pytest.raises(ValueError, match=pattern):
            slam.load_sequence(_write(tmp_path, data))
