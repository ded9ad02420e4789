"""The configuration is typed by its dataclass annotations and checked when the file is read:
wrong types and absurd values are ConfigErrors naming the file, the key and what was
expected; YAML 1.2 numbers are numbers; the defaults survive a write/read round trip."""

import dataclasses
import math
import typing

import pytest

from bsslam.config import SLAMConfig
from bsslam.errors import ConfigError
from bsslam.io.config_file import load_config, write_config


def load_text(tmp_path, text):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    return load_config(path), path


# (YAML text, the key the message must name, words the message must contain)
TYPE_ERRORS = [
    ("frontend:\n  enabled: 'no'\n", "frontend.enabled", "true or false"),
    ("mapping:\n  extend: 'false'\n", "mapping.extend", "true or false"),
    ("relocalize: 1\n", "relocalize", "true or false"),
    ("segmentation:\n  min_points: 8.5\n", "segmentation.min_points", "an integer"),
    ("spline:\n  degree: 3.5\n", "spline.degree", "an integer"),
    ("spline:\n  degree: true\n", "spline.degree", "an integer"),
    ("observation:\n  iterations: 2.5\n", "observation.iterations", "an integer"),
    ("frontend:\n  icp_iterations: 100000000000000000000\n", "frontend.icp_iterations", "an integer below"),
    ("observation:\n  sigma_range_m: fast\n", "observation.sigma_range_m", "a number"),
    ("observation:\n  sigma_range_m: .nan\n", "observation.sigma_range_m", "a finite number"),
    ("observation:\n  sigma_range_m: .inf\n", "observation.sigma_range_m", "a finite number"),
    ("mapping:\n  fit_bias_sigmas: many\n", "mapping.fit_bias_sigmas", "a number or null"),
    ("segmentation:\n  no_return_m: [1]\n", "segmentation.no_return_m", "a number or null"),
    ("mode: mapping\n", "mode", "one of 'slam', 'localization'"),
    ("submaps:\n  loop_outliers: huber\n", "submaps.loop_outliers", "one of 'cauchy', 'gnc'"),
    ("initial_pose_sigma: [0.1, 0.1]\n", "initial_pose_sigma", "a list of 3 values"),
    ("initial_pose_sigma: [0.1, x, 0.1]\n", "initial_pose_sigma[1]", "a number"),
]


@pytest.mark.parametrize("text, key, words", TYPE_ERRORS)
def test_a_value_of_the_wrong_type_names_file_key_and_type(tmp_path, text, key, words):
    with pytest.raises(ConfigError) as info:
        load_text(tmp_path, text)
    message = str(info.value)
    line = text.count("\n")     # the bad value is on the last line of each text
    assert message.startswith(f"{tmp_path / 'bad.yaml'}:{line}: {key}: expected {words}"), message


# values of the right type outside what is physical or affordable
RANGE_ERRORS = [
    ("observation:\n  sigma_range_m: 1e300\n", "observation.sigma_range_m"),       # once an OverflowError
    ("frontend:\n  search_window_m: 1e4\n", "frontend.search_window_m"),           # once 596 GiB
    ("segmentation:\n  no_return_m: -1\n", "segmentation.no_return_m"),            # once an empty map, exit 0
    ("segmentation:\n  no_return_m: 0.05\n", "segmentation.no_return_m"),
    ("spline:\n  degree: 7\n", "spline.degree"),
    ("observation:\n  sigma_model_m: 50.0\n", "observation.sigma_model_m"),
    ("motion:\n  a_phi_rad: 100.0\n", "motion.a_phi_rad"),
    ("frontend:\n  range_sigma_m: 1.0e3\n", "frontend.range_sigma_m"),
    ("frontend:\n  max_range_m: 1.0e5\n", "frontend.max_range_m"),
    ("frontend:\n  max_range_m: 100\n  fine_step_m: 0.02\n", "fine likelihood field"),
    ("frontend:\n  fine_step_m: 0.001\n  fine_sigma_m: 0.002\n", "coarse_step_m / fine_step_m"),
    ("frontend:\n  search_window_m: 4.0\n  coarse_step_m: 0.02\n  fine_step_m: 0.01\n", "search_window_m / coarse_step_m"),
    ("frontend:\n  normal_neighbours: 100000\n", "frontend.normal_neighbours"),
    ("observation:\n  iterations: 1000000\n", "observation.iterations"),
    ("initial_pose_sigma: [1.0e9, 0, 0]\n", "initial_pose_sigma"),
    ("submaps:\n  loop_inlier_probability: 1.0\n", "submaps.loop_inlier_probability"),
]


@pytest.mark.parametrize("text, key", RANGE_ERRORS)
def test_a_value_out_of_range_names_file_and_key(tmp_path, text, key):
    with pytest.raises(ConfigError) as info:
        load_text(tmp_path, text)
    message = str(info.value)
    assert message.startswith(f"{tmp_path / 'bad.yaml'}:") and key in message, message


def test_the_line_is_that_of_the_key_even_in_a_longer_file(tmp_path):
    text = "# my settings\nspline:\n  degree: 2\n\nfrontend:\n  enabled: true\n  max_range_m: 100\n  fine_step_m: 0.02\n"
    with pytest.raises(ConfigError) as info:
        load_text(tmp_path, text)
    assert str(info.value).startswith(f"{tmp_path / 'bad.yaml'}:5: frontend: the fine likelihood field")
    with pytest.raises(ConfigError) as info:
        load_text(tmp_path, text.replace("enabled: true", "enabled: 'yes'"))
    assert str(info.value).startswith(f"{tmp_path / 'bad.yaml'}:6: frontend.enabled: expected true or false")


def test_yaml_1_2_floats_are_numbers(tmp_path):
    config, _ = load_text(tmp_path, "observation:\n  sigma_range_m: 3.0e-2\n  sigma_model_m: 25e-4\n"
                                    "  r_inflation: 1E1\nfrontend:\n  covariance_inflation: +1.0e1\n")
    assert config.observation.sigma_range_m == 0.03
    assert config.observation.sigma_model_m == 0.0025
    assert config.observation.r_inflation == 10.0 and config.frontend.covariance_inflation == 10.0


def test_a_quoted_number_stays_a_string_and_is_refused(tmp_path):
    with pytest.raises(ConfigError, match="observation.sigma_range_m: expected a number"):
        load_text(tmp_path, "observation:\n  sigma_range_m: '1.0e-2'\n")


def test_integers_are_accepted_for_numbers_and_become_floats(tmp_path):
    config, _ = load_text(tmp_path, "spline:\n  knot_spacing_m: 2\nsegmentation:\n  no_return_m: 30\n")
    assert config.spline.knot_spacing_m == 2.0 and type(config.spline.knot_spacing_m) is float
    assert type(config.segmentation.no_return_m) is float


def test_yaml_booleans_and_null_where_allowed(tmp_path):
    config, _ = load_text(tmp_path, "frontend:\n  enabled: false\nmapping:\n  extend: no\n  fit_bias_sigmas: null\n")
    assert config.frontend.enabled is False and config.mapping.extend is False
    assert config.mapping.fit_bias_sigmas is None


def test_the_defaults_round_trip_exactly(tmp_path):
    default = SLAMConfig()
    write_config(tmp_path / "config.yaml", default)
    back = load_config(tmp_path / "config.yaml")
    assert back == default
    # and every value comes back with its annotated type, not merely an equal one
    for section in dataclasses.fields(SLAMConfig):
        value = getattr(back, section.name)
        if dataclasses.is_dataclass(value):
            hints = typing.get_type_hints(type(value))
            for f in dataclasses.fields(value):
                v = getattr(value, f.name)
                if hints[f.name] in (bool, int, float):
                    assert type(v) is hints[f.name], (section.name, f.name, v)


def test_a_non_default_config_with_small_and_large_floats_round_trips(tmp_path):
    config = SLAMConfig.from_dict({"observation": {"sigma_range_m": 1e-7, "gate_probability": 0.999999},
                                   "frontend": {"keyframe_angle_rad": math.radians(7.3)},
                                   "initial_pose_sigma": [1e-9, 999.0, 0.25]})
    write_config(tmp_path / "c.yaml", config)
    assert load_config(tmp_path / "c.yaml") == config


def test_every_field_has_a_type_the_checker_knows():
    """A new field with an annotation the generic checker cannot read fails here, not in a
    user's run."""
    for section in dataclasses.fields(SLAMConfig):
        default = getattr(SLAMConfig(), section.name)
        data = dataclasses.asdict(default) if dataclasses.is_dataclass(default) else default
        SLAMConfig.from_dict({section.name: data})
