"""The one telemetry column schema: the header and a row's layout come from the same blocks, so a row given
by name lands under its columns, a block not given is empty, and a misspelled key or a vector of the wrong
length is refused rather than shifting or emptying columns without a word."""

from __future__ import annotations

import pytest

from hil.runtime.telemetry import TelemetrySchema, board_columns, telemetry_columns


def test_each_value_lands_under_its_named_columns_and_the_rest_is_empty():
    schema = TelemetrySchema(2)
    row = schema.row(
        {"t": 1.5, "phase": 2, "gimbal_angle": [0.1, 0.2], "pulse": [1500, 1501, 1502, None], "faults": 4}
    )
    assert len(row) == len(schema.columns) == len(telemetry_columns(2))
    cells = dict(zip(schema.columns, row, strict=True))
    assert cells["t"] == 1.5 and cells["phase"] == 2 and cells["faults"] == 4
    assert (cells["gimbal_angle_0"], cells["gimbal_angle_1"]) == (0.1, 0.2)
    assert [cells[f"pulse_{kind}_{i}"] for i in range(2) for kind in ("gimbal", "rotor")] == [
        1500,
        1501,
        1502,
        None,
    ]
    given = {"t", "phase", "gimbal_angle_0", "gimbal_angle_1", "faults"} | {
        f"pulse_{k}_{i}" for i in range(2) for k in ("gimbal", "rotor")
    }
    assert all(cells[c] is None for c in schema.columns if c not in given)


def test_the_board_columns_are_the_board_blocks_in_column_order():
    schema = TelemetrySchema(3)
    assert list(schema.board_columns) == board_columns(3)
    assert [c for c in schema.columns if c in set(schema.board_columns)] == list(schema.board_columns)


def test_an_unknown_key_or_a_vector_of_the_wrong_length_is_refused():
    schema = TelemetrySchema(2)
    with pytest.raises(KeyError, match="gimbal_angles"):
        schema.row({"gimbal_angles": [0.0, 0.0]})
    with pytest.raises(ValueError, match="rotor_speed"):
        schema.row({"rotor_speed": [1.0, 2.0, 3.0]})
