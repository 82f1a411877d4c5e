"""BCConfig's checks, in process (imitation/algorithms/bc_config.py): each bound at its edge, the
frames' crop and size, the flags' text turned into fields, and what a data-parallel run refuses."""

from __future__ import annotations

import pytest

from imitation.algorithms.bc_config import BCConfig, _crop, _image_size
from imitation.data.frame_transform import FrameTransform
from imitation.data.image_resize import MAX_SIDE
from imitation.errors import ConfigError, ImitationError


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"loss": "l1"}, "loss must be one of nll, mse, got 'l1'"),
        ({"previous_action": "yes"}, "previous_action must be one of auto, on, off, got 'yes'"),
        ({"prediction": "velocity"}, "prediction must be one of sample, noise, got 'velocity'"),
        ({"frame_stack": 0}, "frame_stack must be in [1, 64], got 0"),
        ({"frame_stack": 65}, "frame_stack must be in [1, 64], got 65"),
        ({"random_shift": -1}, "random_shift must be at least 0 pixels, got -1"),
        ({"threads": 0}, "threads must be in [1, 1024], got 0"),
        ({"threads": 1025}, "threads must be in [1, 1024], got 1025"),
        ({"steps": "some"}, "steps must be one of all, human, got 'some'"),
        ({"stream_memory": 0}, "stream_memory must be at least 1 byte, got 0"),
        ({"epochs": 0}, "epochs must be at least 1, got 0"),
        ({"batch_size": 0}, "batch_size must be at least 1, got 0"),
        ({"patience": 0}, "patience must be at least 1, got 0"),
        ({"learning_rate": 0.0}, "learning_rate must be a positive number below 1e30, got 0.0"),
        ({"learning_rate": 1e30}, "learning_rate must be a positive number below 1e30, got 1e+30"),
    ],
)
def test_each_setting_out_of_range_is_refused_naming_it(fields: dict, message: str) -> None:
    with pytest.raises(ConfigError) as refused:
        BCConfig(**fields).validate(continuous=True)
    assert str(refused.value) == message and refused.value.owner == "BCConfig"


@pytest.mark.parametrize(
    "fields",
    [
        {"frame_stack": 1},
        {"frame_stack": 64},
        {"threads": 1},
        {"threads": 1024},
        {"random_shift": 0},
        {"stream_memory": 1},
        {"epochs": 1, "batch_size": 1, "patience": 1},
        {"learning_rate": 1e29},
        {"steps": "human"},
        {"loss": "mse"},
    ],
)
def test_each_setting_at_its_edge_is_taken(fields: dict) -> None:
    BCConfig(**fields).validate(continuous=True)


def test_mse_is_for_continuous_actions_only() -> None:
    BCConfig(loss="mse").validate(continuous=True)
    with pytest.raises(ConfigError, match="^loss mse is for continuous"):
        BCConfig(loss="mse").validate(continuous=False)


def test_the_frames_load_cropped_then_resized_as_the_fields_say() -> None:
    assert BCConfig().frame_transform() is None
    assert BCConfig(image_size=[96, 64]).frame_transform() == FrameTransform((96, 64), None)
    assert BCConfig(crop=[0, 2, 1, 3]).frame_transform() == FrameTransform(None, (0, 2, 1, 3))
    assert BCConfig(image_size=[1, MAX_SIDE], crop=[5, 6, 7, 8]).frame_transform() == FrameTransform((1, MAX_SIDE), (5, 6, 7, 8))


@pytest.mark.parametrize(
    ("fields", "field"),
    [
        ({"image_size": [0, 8]}, "image_size"),
        ({"image_size": [8, MAX_SIDE + 1]}, "image_size"),
        ({"image_size": [8]}, "image_size"),
        ({"image_size": [8, 8, 8]}, "image_size"),
        ({"image_size": (8, 8)}, "image_size"),
        ({"image_size": [8.0, 8]}, "image_size"),
        ({"image_size": [True, 8]}, "image_size"),
        ({"crop": [0, 0, 0, 8]}, "crop"),
        ({"crop": [0, 0, 8, 0]}, "crop"),
        ({"crop": [-1, 0, 8, 8]}, "crop"),
        ({"crop": [0, 0, 8]}, "crop"),
        ({"crop": [0, MAX_SIDE + 1, 8, 8]}, "crop"),
    ],
)
def test_a_malformed_crop_or_size_is_refused_naming_it(fields: dict, field: str) -> None:
    with pytest.raises(ConfigError) as refused:
        BCConfig(**fields).validate(continuous=True)
    assert refused.value.field == field and refused.value.owner == "BCConfig"
    assert f"1 to {MAX_SIDE}, got " in str(refused.value)


def test_the_flags_text_becomes_the_fields_lists() -> None:
    assert _image_size("96x128") == [96, 128] and _crop("1,2,3,4") == [1, 2, 3, 4]
    with pytest.raises(ImitationError, match="^--image-size 96: give HEIGHTxWIDTH"):
        _image_size("96")
    with pytest.raises(ImitationError, match="^--crop '1,2': give the rectangle"):
        _crop("1,2")


def test_a_data_parallel_run_splits_batches_evenly_and_streams_nothing() -> None:
    BCConfig(batch_size=256).validate_data_parallel(4)
    with pytest.raises(ConfigError, match=r"^batch_size must be a multiple of the 3 torchrun processes .* got 256$"):
        BCConfig(batch_size=256).validate_data_parallel(3)
    with pytest.raises(ConfigError, match=r"^batch_size must be a multiple of the 2 torchrun processes .* got 1$"):
        BCConfig(batch_size=1).validate_data_parallel(2)
    with pytest.raises(ConfigError, match="^stream_memory streams no data under torchrun"):
        BCConfig(stream_memory=1024).validate_data_parallel(1)
