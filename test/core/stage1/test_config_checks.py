"""Stage1Config refuses values of the wrong type and crossed pairs with a ConfigError naming the parameter (the
`--param` parser and the ROS parameters both build one), and names the nearest known key for a misspelt one."""

from __future__ import annotations

import numpy as np
import pytest

from pass3d_ros.core.stage1.config import ConfigError, Stage1Config, closest, parse_params


@pytest.mark.parametrize(("item", "says"), [
    ("th_dist='abc'", "th_dist='abc' must be a number"),
    ("th_dist=[1]", "th_dist=[1] must be a number"),
    ("th_dist=None", "th_dist=None must be a number"),
    ("th_dist=True", "th_dist=True must be a number"),
    ("enlarge=0.1", "enlarge=0.1 must be a list of numbers"),
    ("enlarge=(0.1, 'a', 0.4)", "enlarge=(0.1, 'a', 0.4) must be a list of numbers"),
    ("n_seg=3.5", "n_seg=3.5 must be an integer"),
    ("n_seg=True", "n_seg=True must be an integer"),
    ("sensor=16", "sensor='16' not one of auto"),  # a string field reads its text as it is
    ("sensor=vlp99", "sensor='vlp99' not one of auto"),
    ("th_dist=abc", "th_dist=abc must be a number"),
    ("n_seg=abc", "n_seg=abc must be an integer"),
    ("enlarge=a,b,c", "enlarge=a,b,c must be a list of numbers"),
    ("enlarge=0.1,0.1", "enlarge needs 3 values"),
    ("ground_thread=maybe", "ground_thread=maybe must be true or false"),
    ("stage1.th_dsit=0.2", "stage1.th_dsit (did you mean stage1.th_dist?)"),
    ("stage2.th_dist=0.2", "unknown parameter(s) stage2.th_dist"),
    ("ground_thread=1", "ground_thread=1 must be true or false"),
    ("max_top=0.5", "max_top=0.5 is below min_top=0.9"),
    ("th_num_floor=40", "th_num_near=30 is below th_num_floor=40"),
    ("th_dsit=0.2", "th_dsit (did you mean th_dist?)"),
])
def test_bad_param_is_a_config_error_naming_it(item: str, says: str) -> None:
    with pytest.raises(ConfigError) as caught:
        parse_params([item])
    assert says in str(caught.value)


def test_numbers_are_normalised() -> None:
    config = Stage1Config(th_dist=np.float32(0.25), n_seg=np.int64(4), th_num_near=40, enlarge=[1, 1, 1])
    assert type(config.th_dist) is float and type(config.n_seg) is int and type(config.th_num_near) is float
    assert config.enlarge == (1.0, 1.0, 1.0)
    assert parse_params(["max_top=1.0", "min_top=1.0"]).max_top == 1.0, "equal ends are allowed"


def test_validate_after_a_change_sees_the_crossed_pair() -> None:
    config = Stage1Config()
    config.max_top = 0.1
    with pytest.raises(ConfigError, match=r"max_top=0\.1 is below min_top"):
        config.validate()


def test_closest_name() -> None:
    assert closest("stage1.th_dsit", ["stage1.th_dist", "input_topic"]) == "stage1.th_dist"
    assert closest("zzz", ["input_topic"]) is None


def test_a_string_field_still_refuses_a_value_of_another_type() -> None:
    with pytest.raises(ConfigError, match="sensor=16 must be a string"):
        Stage1Config(sensor=16)


@pytest.mark.parametrize(("items", "expected"), [
    (["stage1.sensor=pandar64"], {"sensor": "pandar64"}),
    (["sensor=pandar64"], {"sensor": "pandar64"}),
    (["sensor='pandar64'"], {"sensor": "pandar64"}),
    (['sensor="os1-64"'], {"sensor": "os1-64"}),
    (["stage1.th_dist=0.25", "n_seg=4"], {"th_dist": 0.25, "n_seg": 4}),
    (["enlarge=0.1,0.2,0.5"], {"enlarge": (0.1, 0.2, 0.5)}),
    (["stage1.enlarge=[0.1,0.2,0.5]"], {"enlarge": (0.1, 0.2, 0.5)}),
    (["enlarge=(0.1, 0.2, 0.5)"], {"enlarge": (0.1, 0.2, 0.5)}),
    (["enlarge=0.1 0.2 0.5"], {"enlarge": (0.1, 0.2, 0.5)}),
    (["enlarge=1,1,1"], {"enlarge": (1.0, 1.0, 1.0)}),
    (["ground_thread=false"], {"ground_thread": False}),
    (["stage1.sensor_scaling=False"], {"sensor_scaling": False}),
    (["ground_thread=TRUE"], {"ground_thread": True}),
    (["th_num_near=40"], {"th_num_near": 40.0}),
    ([" th_dist = 0.2 "], {"th_dist": 0.2}),
    (["th_dist=0.2", "stage1.th_dist=0.35"], {"th_dist": 0.35}),  # the later one wins
])
def test_param_names_and_values_as_the_node_or_bare(items: list[str], expected: dict) -> None:
    """`--param` takes the node's name (stage1.KEY) or the bare one, and reads each value by its field's type:
    strings without quotes, true / false, three numbers however written; Python literals as before."""
    config = parse_params(items)
    for name, value in expected.items():
        assert getattr(config, name) == value and type(getattr(config, name)) is type(value), name


def test_stage2_config_is_the_segmentation_nodes_stage2_parameters():
    """Stage2Config holds one default, description and range per stage-2 setting; the node's parameter table takes
    them from it, so the node, the shipped YAML and docs/parameters.md cannot drift apart."""
    from pass3d_ros.core.stage2.config import Stage2Config, parameter_table
    from pass3d_ros.ros import segmentation_node

    table = parameter_table()
    assert {"weights", "threads", "max_proposals", "intensity_match", "classifier", "device"} <= set(table)
    for name, entry in table.items():
        assert segmentation_node.NODE_PARAMETERS[name] == entry, name
    assert Stage2Config().to_dict() == {name: entry[0] for name, entry in table.items()}
    assert Stage2Config(min_confidence=1).min_confidence == 1.0  # an int is a number
    with pytest.raises(ConfigError, match=r"max_proposals=0 outside \[1, 1024\]"):
        Stage2Config(max_proposals=0)
    with pytest.raises(ConfigError, match="threads=True must be an integer"):
        Stage2Config(threads=True)
    with pytest.raises(ConfigError, match=r"unknown parameter\(s\) max_proposal \(did you mean max_proposals\?\)"):
        Stage2Config.from_mapping({"max_proposal": 3})


def test_the_track_settings_reach_the_tracker() -> None:
    """Stage2Config's track_* values are the tracker's, its defaults TrackerConfig's, and a value out of range is
    refused by name."""
    from pass3d_ros.classes import CAR, PEDESTRIAN
    from pass3d_ros.core.pipeline import ProposalSegmenter
    from pass3d_ros.core.stage2 import open_classifier
    from pass3d_ros.core.stage2.config import Stage2Config
    from pass3d_ros.core.stream.tracks import TrackerConfig

    assert Stage2Config().tracker_config() == TrackerConfig()
    settings = Stage2Config(tracking=True, track_gate_pedestrian=0.8, track_min_hits=4, track_max_misses=6,
                            track_vote_window=3)
    segmenter = ProposalSegmenter(open_classifier(None, "size_rules"), tracking=settings.tracking,
                                  tracker_config=settings.tracker_config())
    config = segmenter.tracker.config
    assert (config.gate(PEDESTRIAN), config.gate(CAR)) == (0.8, TrackerConfig().gate(CAR))
    assert (config.min_hits, config.max_misses, config.vote_window) == (4, 6, 3)
    with pytest.raises(ValueError, match="track_min_hits"):
        Stage2Config(track_min_hits=0)
