"""Every command fails well on bad input: non-zero exit, one line naming the flag or file, no
traceback, nothing half-written. Per script: a missing file, a corrupt file and an out-of-range
number (the sweep of the core issue), run as a user would, in a subprocess."""

import os
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad")
    (d / "corrupt.npz").write_bytes(b"this is not a zip file")
    (d / "corrupt.json").write_text("{ not json")
    (d / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    seq = d / "seq_corrupt"
    seq.mkdir()
    (seq / "sequence.json").write_text('{"intrinsics": ')
    empty = d / "empty_dir"
    empty.mkdir()
    (d / "a_file").write_text("x")
    # a BOP scene folder (issue 24 item 5): only scene_gt.json, enough for the checks before any work
    (d / "bop").mkdir()
    (d / "bop" / "scene_gt.json").write_text("{}")
    # volumon predict's own inputs: a readable image, good boxes and bad ones (issue 26 item 5)
    import cv2
    import numpy as np

    cv2.imwrite(str(d / "image.png"), np.full((96, 128, 3), 127, np.uint8))
    (d / "boxes.json").write_text("[[10, 10, 60, 50]]")
    (d / "box_str.json").write_text('{"box": "a"}')
    (d / "box_5.json").write_text("[[10, 10, 60, 50], [1, 2, 3, 4, 5]]")
    (d / "box_nan.json").write_text("[[10, 10, NaN, 50]]")
    (d / "box_huge.json").write_text("[[0, 0, 1e9, 1e9]]")
    # roshan's sequences (issue 26 item 6): no detections anywhere (a misspelt key), a huge box, a
    # frame image that cannot be read
    import json

    def sequence(name, frame, image=None):
        (d / name).mkdir()
        frame = {"camera_T_world": np.eye(4).tolist(), **frame}
        if image is not None:
            (d / name / "frame0.png").write_bytes(image)
            frame["image"] = "frame0.png"
        data = {"K": [[500.0, 0, 320], [0, 500, 240], [0, 0, 1]], "image_size": [640, 480], "frames": [frame]}
        (d / name / "sequence.json").write_text(json.dumps(data))

    det = {"box": [10, 20, 50, 60], "class": "car", "id": 0}
    sequence("seq_misspelt", {"detection": [det]})
    sequence("seq_huge_box", {"detections": [{**det, "box": [0, 0, 1e9, 1e9]}]})
    sequence("seq_bad_image", {"detections": [det]}, image=b"\x89PNG\r\n\x1a\n garbage")
    return d


def _cases(d):
    out = d / "out"  # each case writes (if at all) under out / <its id prefix>
    return [
        # (id, argv, words the one error line must contain)
        ("roshan-missing", ["infer/roshan.py", "--sequence", str(d / "nope"), "--out", str(out / "r1")], ["nope"]),
        (
            "roshan-corrupt",
            ["infer/roshan.py", "--sequence", str(d / "seq_corrupt"), "--out", str(out / "r2")],
            ["sequence.json"],
        ),
        (
            "roshan-range",
            ["infer/roshan.py", "--simulate", "forward", "--frames", "0", "--out", str(out / "r3")],
            ["--frames"],
        ),
        (
            "roshan-no-detections",
            ["-m", "jaxsem.cli", "roshan", "--sequence", str(d / "seq_misspelt"), "--out", str(out / "r4")],
            ["seq_misspelt/sequence.json", "detections", "'detection'"],
        ),
        (
            "roshan-huge-box",
            ["-m", "jaxsem.cli", "roshan", "--sequence", str(d / "seq_huge_box"), "--out", str(out / "r5")],
            ["seq_huge_box/sequence.json", "frames[0].detections[0].box", "10 times"],
        ),
        (
            "roshan-unreadable-image",
            ["-m", "jaxsem.cli", "roshan", "--sequence", str(d / "seq_bad_image"), "--out", str(out / "r6")],
            ["frames[0].image", "frame0.png"],
        ),
        ("plan-missing", ["infer/plan.py", "--map", str(d / "nope.npz"), "--out", str(out / "p1.png")], ["nope.npz"]),
        (
            "plan-corrupt",
            ["infer/plan.py", "--map", str(d / "corrupt.npz"), "--out", str(out / "p2.png")],
            ["corrupt.npz"],
        ),
        ("plan-range", ["infer/plan.py", "--n", "0", "--out", str(out / "p3.png")], ["--n"]),
        (
            "expert-range",
            ["infer/make_expert_data.py", "--sample-prob", "nan", "--out", str(out / "e1")],
            ["--sample-prob"],
        ),
        ("expert-workers", ["infer/make_expert_data.py", "--workers", "0", "--out", str(out / "e2")], ["--workers"]),
        ("expert-out-file", ["infer/make_expert_data.py", "--out", str(d / "a_file")], ["a_file"]),
        (
            "volumon-missing",
            [
                "infer/volumon.py",
                "--image",
                str(d / "nope.png"),
                "--boxes",
                str(d / "corrupt.json"),
                "--out",
                str(out / "v1"),
            ],
            ["nope.png"],
        ),
        (
            "volumon-corrupt",
            [
                "infer/volumon.py",
                "--image",
                str(d / "corrupt.png"),
                "--boxes",
                str(d / "corrupt.json"),
                "--out",
                str(out / "v2"),
            ],
            ["corrupt"],
        ),
        ("volumon-range", ["infer/volumon.py", "--split", "test", "--num", "0", "--out", str(out / "v3")], ["--num"]),
        # issue 26 item 5: every input of volumon predict checked before any work, naming the flag / file
        *[
            (
                f"volumon-{name}",
                ["-m", "jaxsem.cli", "volumon", "predict", "--image", str(d / "image.png"), "--boxes", str(d / boxes)]
                + extra
                + ["--out", str(out / f"v-{name}")],
                words,
            )
            for name, boxes, extra, words in [
                ("class-id", "boxes.json", ["--class-id", "99"], ["--class-id", "99", "0 to 3", "soup_can"]),
                ("class-id-negative", "boxes.json", ["--class-id", "-1"], ["--class-id", "-1"]),
                ("box-string", "box_str.json", [], ["--boxes", "box_str.json", "[0].box", "'a'"]),
                ("box-5-numbers", "box_5.json", [], ["--boxes", "box_5.json", "[1]", "[1, 2, 3, 4, 5]"]),
                ("box-nan", "box_nan.json", [], ["--boxes", "box_nan.json", "[0]", "finite"]),
                ("box-huge", "box_huge.json", [], ["--boxes", "box_huge.json", "[0]", "10 times"]),
                ("boxes-corrupt", "corrupt.json", [], ["--boxes", "corrupt.json", "JSON"]),
                ("K-text", "boxes.json", ["--K", "abc"], ["--K", "abc"]),
                ("K-nan", "boxes.json", ["--K", "nan,110,63.5,47.5"], ["--K", "nan"]),
                ("K-focal", "boxes.json", ["--K", "0,110,63.5,47.5"], ["--K", "fx, fy > 0"]),
            ]
        ],
        ("train-volumon-range", ["train/volumon.py", "--workdir", str(out / "tv"), "--steps", "-5"], ["--steps"]),
        (
            "train-volumon-workdir-file",
            ["train/volumon.py", "--workdir", str(d / "a_file"), "--steps", "1"],
            ["a_file"],
        ),
        ("train-lsd-missing", ["train/lsd.py", "--data", str(d / "nope"), "--workdir", str(out / "tl1")], ["nope"]),
        (
            "train-lsd-empty",
            ["train/lsd.py", "--data", str(d / "empty_dir"), "--workdir", str(out / "tl2")],
            ["empty_dir"],
        ),
        (
            "train-lsd-range",
            ["train/lsd.py", "--data", str(d / "empty_dir"), "--workdir", str(out / "tl3"), "--batch-size", "0"],
            ["--batch-size"],
        ),
        (
            "adopt-lift-detector",
            ["train/adopt_volumon_lift.py", "--detector", str(d / "nope.npz"), "--out", str(out / "adopted")],
            ["--detector", "nope.npz"],
        ),
        (
            "adopt-lift-out",
            ["train/adopt_volumon_lift.py", "--detector", "lmo-rcnn", "--out", str(d / "nodir" / "adopted")],
            ["--out", "nodir"],
        ),
        (
            "rcnn-train-val-to",
            [
                "train/volumon_rcnn.py",
                "--workdir",
                str(out / "rcnn"),
                "--renders",
                str(out / "renders"),
                "--models",
                str(d / "empty_dir"),
                "--val-from",
                "500",
                "--val-to",
                "400",
            ],
            ["--val-to", "400"],
        ),
        (
            "rcnn-train-zoom-below-one",
            ["train/volumon_rcnn.py", "--workdir", str(out / "rcnn"), "--renders", str(out / "renders")]
            + ["--models", str(d / "empty_dir"), "--zoom-renders", "0.5"],
            ["--zoom-renders", "0.5"],
        ),
        (
            "rcnn-validation-folds",
            ["benchmarks/volumon/volumon_rcnn_validation.py", "--data", str(d / "bop"), "--models", "lmo-rcnn"]
            + ["--folds", "lmo-rcnn:300", "--out", str(out / "val")],
            ["--folds", "lmo-rcnn:300"],
        ),
        (
            "roshan-real-folds-gap",
            ["benchmarks/roshan/roshan_real.py", "--scene", str(d / "bop"), "--split", "tune", "--json"]
            + [str(out / "rr.json"), "--frames", "300", "600", "--detector-folds", "lmo-rcnn:300-500"],
            ["--detector-folds", "cover"],
        ),
        (
            "roshan-real-folds-overlap",
            ["benchmarks/roshan/roshan_real.py", "--scene", str(d / "bop"), "--split", "tune", "--json"]
            + [str(out / "rr.json"), "--frames", "300", "600", "--detector-folds"]
            + ["lmo-rcnn:300-500", "lmo-rcnn:450-600"],
            ["--detector-folds", "overlaps"],
        ),
        (
            "roshan-vs-quadricslam-rewrite-missing",
            ["benchmarks/roshan/roshan_vs_quadricslam.py", "--rewrite-md", "--out", str(out / "none"), "--name", "x"],
            ["--rewrite-md", "x.json"],
        ),
        (
            "roshan-real-frames-split",
            ["benchmarks/roshan/roshan_real.py", "--scene", str(d / "bop"), "--split", "test", "--json"]
            + [str(out / "rr.json"), "--frames", "300", "500", "--detector", "lmo-rcnn"],
            ["--frames", "test"],
        ),
        ("jaxsem-demo-parts", ["-m", "jaxsem.cli", "demo", "--parts", "bogus", "--out", str(out / "demo")], ["bogus"]),
        ("jaxsem-eval-range", ["-m", "jaxsem.cli", "volumon", "eval", "--num", "0"], ["--num"]),
        ("jaxsem-eval-workdir", ["-m", "jaxsem.cli", "volumon", "eval", "--workdir", str(d / "nope")], ["nope"]),
        (
            "jaxsem-eval-data",
            ["-m", "jaxsem.cli", "volumon", "eval", "--data", str(d / "nodata")],
            ["--data", "nodata"],
        ),
        (
            "train-volumon-data",
            ["train/volumon.py", "--workdir", str(out / "td"), "--data", str(d / "nodata")],
            ["--data", "nodata"],
        ),
        # issue 24 item 3: the LM-O desk renders
        (
            "make-lmo-renders-models",
            [
                "-m",
                "jaxsem.volumon.data.make_lmo_renders",
                "--models",
                str(d / "nomodels"),
                "--out",
                str(out / "r"),
                "--frames",
                "1",
            ],
            ["--models", "nomodels"],
        ),
        # issue 24 item 5: volumon eval on a BOP scene
        *[
            (f"jaxsem-eval-bop-{name}", ["-m", "jaxsem.cli", "volumon", "eval"] + argv, words)
            for name, argv, words in [
                ("missing-scene", ["--data", str(d / "no_scene"), "--split", "tune"], ["--data", "no_scene"]),
                ("split-unknown", ["--data", str(d / "bop"), "--split", "val"], ["--split", "val"]),
                ("split-missing", ["--data", str(d / "bop")], ["--split"]),
                (
                    "visible-range",
                    ["--data", str(d / "bop"), "--split", "tune", "--min-visible", "1.5"],
                    ["--min-visible"],
                ),
                (
                    "model-unknown",
                    ["--model", "lmo2", "--data", str(d / "bop"), "--split", "tune"],
                    ["--model", "lmo2", "lmo"],  # the message lists the shipped names, the LM-O model among them
                ),
                (
                    "model-path",
                    ["--model", str(d / "nope.npz"), "--data", str(d / "bop"), "--split", "tune"],
                    ["--model"],
                ),
                ("split-not-bop", ["--split", "tune"], ["--split"]),
            ]
        ],
        # issue 24 item 6: volumon predict on a BOP frame
        (
            "volumon-bop-frame-missing",
            ["-m", "jaxsem.cli", "volumon", "predict", "--data", str(d / "bop"), "--out", str(out / "vb")],
            ["--frame"],
        ),
        (
            "volumon-bop-not-a-scene",
            [
                "-m",
                "jaxsem.cli",
                "volumon",
                "predict",
                "--data",
                str(d / "empty_dir"),
                "--frame",
                "3",
                "--out",
                str(out / "vb2"),
            ],
            ["--data"],
        ),
        (
            "volumon-predict-model-unknown",
            [
                "-m",
                "jaxsem.cli",
                "volumon",
                "predict",
                "--model",
                "lmo2",
                "--data",
                str(d / "bop"),
                "--frame",
                "3",
                "--out",
                str(out / "vb3"),
            ],
            ["--model", "lmo2", "lmo"],
        ),
    ]


CASE_IDS = [c[0] for c in _cases(pathlib.Path("/x"))]


@pytest.mark.slow
@pytest.mark.parametrize("case_id", CASE_IDS)
def test_bad_input_gives_one_line_naming_it(case_id, files):
    _, argv, words = next(c for c in _cases(files) if c[0] == case_id)
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONWARNINGS": "ignore"}
    cmd = [sys.executable, *(argv if argv[0] == "-m" else [str(ROOT / argv[0]), *argv[1:]])]
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300, check=False)
    err_lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode != 0, f"exit 0 on bad input; stdout: {proc.stdout[-500:]}"
    assert "Traceback" not in proc.stderr, proc.stderr[-2000:]
    # argparse prints its usage line before the error; the error itself is the last line.
    assert err_lines, "no error message"
    last = err_lines[-1]
    for word in words:
        assert word in last, f"{word!r} not named in: {last}"
    # Nothing half-written: the output paths named on the command line hold no files.
    for arg in argv:
        path = pathlib.Path(arg)
        if str(path).startswith(str(files / "out")) and path.exists():
            leftovers = [p for p in ([path] if path.is_file() else path.rglob("*")) if p.is_file()]
            assert not leftovers, f"partial outputs left behind: {leftovers[:5]}"


def test_roshan_refuses_a_bop_camera_with_zero_focal_length(tmp_path, capsys):
    # Issue 45 item 5: it ran to exit 0 with an empty map. Now exit 2, one line naming the file.
    import json

    from jaxsem import cli

    scene = tmp_path / "scene"
    scene.mkdir()
    pose = {"obj_id": 1, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 500]}
    (scene / "scene_gt.json").write_text(json.dumps({"0": [pose]}))
    camera = {"fx": 0.0, "fy": 500.0, "cx": 160.0, "cy": 120.0, "width": 320, "height": 240}
    (scene / "camera.json").write_text(json.dumps(camera))
    argv = ["roshan", "--bop", str(scene), "--out", str(tmp_path / "out"), "--run-dir", str(tmp_path / "run")]
    assert cli.main(argv) == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1 and "camera.json: fx: expected a positive number, got 0" in lines[0], lines
    assert not (tmp_path / "out" / "map.json").exists()


@pytest.mark.parametrize(
    "extra, flag",
    [
        (["--simulate", "forward", "--classes", "mine.json"], "--classes"),  # the file would go unread
        (["--sequence", "seq", "--write-sequence", "copy"], "--write-sequence"),  # nothing simulated to save
        (["--simulate", "orbit", "--write-sequence", "mine.json"], "--write-sequence"),  # a file: refused first
    ],
    ids=["classes-with-simulate", "write-sequence-without-simulate", "write-sequence-into-a-file"],
)
def test_roshan_refuses_a_flag_its_input_would_ignore(extra, flag, tmp_path, capsys):
    from jaxsem import cli

    (tmp_path / "mine.json").write_text('{"classes": []}')
    extra = [str(tmp_path / a) if a.endswith(".json") else a for a in extra]
    with pytest.raises(SystemExit) as exc:
        cli.main(["roshan", *extra, "--out", str(tmp_path / "out")])
    assert exc.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].startswith(f"jaxsem roshan: error: {flag}:")
    assert not (tmp_path / "out").exists()
