"""The project's YAML reader and writer (``blurtrack.io.yamlio``): the safe loader, exponents
read as numbers as YAML 1.2 reads them, and what is written read back to the same values."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from blurtrack.errors import ConfigError
from blurtrack.io.yamlio import dump_yaml, parse_yaml, read_yaml, write_yaml


@pytest.mark.parametrize(
    ("text", "value"),
    [
        ("3e6", 3e6),
        ("1e-2", 0.01),
        ("-2.5E+3", -2500.0),
        ("1.5e6", 1.5e6),
        (".5e3", 500.0),
        ("+1_000e1", 10000.0),
        ("1.0e-05", 1e-5),  # PyYAML's own resolver already read this one
    ],
)
def test_numbers_with_an_exponent_are_numbers(text: str, value: float) -> None:
    got = parse_yaml(f"x: {text}\n")["x"]
    assert isinstance(got, float) and got == value


@pytest.mark.parametrize("text", ["abc3e6", "3e", "e6", "3e6x", "'3e6'", "1e6.5", "1e6 px"])
def test_what_is_not_a_number_stays_text(text: str) -> None:
    # Negative controls: words, incomplete exponents, quoted numbers, units.
    assert isinstance(parse_yaml(f"x: {text}\n")["x"], str)


def test_the_rest_reads_as_plain_safe_yaml() -> None:
    got = parse_yaml("a: 12\nb: 1.5\nc: .inf\nd: true\ne: null\nf: [1, 2]\n")
    assert got == {"a": 12, "b": 1.5, "c": math.inf, "d": True, "e": None, "f": [1, 2]}
    assert isinstance(got["a"], int)
    with pytest.raises(Exception, match="could not determine a constructor"):
        parse_yaml("x: !!python/object:os.system ls\n")


def test_strings_that_look_like_numbers_are_written_quoted(tmp_path: Path) -> None:
    data = {"name": "3e6", "other": "1.0e6", "n": 3e6, "m": 1e-2, "s": "plain"}
    text = dump_yaml(data, sort_keys=False)
    assert "'3e6'" in text and "'1.0e6'" in text
    assert parse_yaml(text) == data
    write_yaml(tmp_path / "d.yaml", data)
    assert read_yaml(tmp_path / "d.yaml") == data


def test_a_file_with_an_exponent_reads_and_bad_files_are_one_line(tmp_path: Path) -> None:
    (tmp_path / "p.yaml").write_text("dot_flux_eps: 3e6\n")
    assert read_yaml(tmp_path / "p.yaml") == {"dot_flux_eps": 3e6}
    (tmp_path / "bad.yaml").write_text("a: [1, 2\n")
    with pytest.raises(ConfigError, match="is not valid YAML") as err:
        read_yaml(tmp_path / "bad.yaml")
    assert "\n" not in str(err.value)
