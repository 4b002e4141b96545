"""The scripts in ``examples/`` run as a user runs them, and reach their known answers."""

import importlib.util
import pathlib

import numpy as np
import pytest

from jaxsem import slam
from jaxsem.slam._results import RESULTS  # layers: white-box

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"


def _load(name):
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_fit_ellipsoid_to_boxes_recovers_the_truth(optax_promotion):  # the example runs optax.adam
    result = _load("fit_ellipsoid_to_boxes").main()
    assert result["last_loss"] < 1e-3 * result["first_loss"]
    assert result["box_rms_px"] < 0.5
    assert result["center_m"] < 0.01
    assert result["volume_ratio"] == pytest.approx(1.0, abs=0.02)


@pytest.mark.slow
def test_lsd_on_my_grid_goes_through_the_door():
    result = _load("lsd_on_my_grid").main()
    assert result["success"] and result["reason"] == "goal"
    # Through the door at (8, 8.5): at least the two legs' length, and not a long detour.
    legs = ((8 - 3) ** 2 + (8.5 - 3) ** 2) ** 0.5 + ((13 - 8) ** 2 + (8.5 - 7) ** 2) ** 0.5
    assert legs - 0.3 <= result["travelled_m"] <= 1.5 * legs


@pytest.mark.slow
def test_slam_from_my_detections_solves_one_and_many():
    result = _load("slam_from_my_detections").main()
    # The tests run in float64, where this map creeps to the 300-trial budget (GTSAM's 1e-5
    # relative stopping rule) rather than stopping: the answer is what is checked.
    assert result["position_m"] < 1.5 and result["cost"] < 100
    # The direct optimistix call on the same cost, from solve_batch's answer, never goes up.
    assert result["optx_cost"] <= result["cost"] * (1 + 1e-6)
    # A batch solved one map after another gives each map exactly its solo answer (CPU default).
    assert result["many_equals_solo_m"] == 0.0
    assert sorted(result["many_position_m"])[1] < 0.5  # median over the three maps


@pytest.mark.slow
def test_online_slam_on_my_frames_maps_every_car():
    result = _load("online_slam_on_my_frames").main()
    # four cars passed at 4-4.5 m beside a 30 m drive, boxes with 2 px noise, 2 cm odometry noise
    assert max(result["position_m"]) < 0.6 and sorted(result["position_m"])[1] < 0.3
    budget = (RESULTS.max_steps_reached, RESULTS.iterations_reached)
    # converged, or stopped by a step budget (normal while frames arrive)
    assert result["message"] in ("successful", *(slam.result_message(code) for code in budget))


@pytest.mark.slow
def test_volumon_on_my_images_predicts_and_fine_tunes_on_2d_labels(tmp_path):
    result = _load("volumon_on_my_images").main(tmp_path / "run")
    # the dual loss on the user's own labels falls, and held-out photos of the same object improve
    assert result["last_dual"] < 0.5 * result["first_dual"]
    assert np.median(result["after_m"]) < np.median(result["before_m"])
    assert np.median(result["after_m"]) < 0.08
