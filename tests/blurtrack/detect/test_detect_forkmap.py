"""``fork_call``: one computation in a forked process, its value or its error here."""

from __future__ import annotations

import os

import numpy as np
import pytest

from blurtrack.detect.forkmap import can_fork, fork_call
from blurtrack.errors import DetectionError, GeometryError

needs_fork = pytest.mark.skipif(not can_fork(), reason="the platform cannot fork")


def _values() -> tuple[int, np.ndarray]:
    return os.getpid(), np.arange(12.0).reshape(3, 4) ** 0.5


def _refuse() -> None:
    raise GeometryError("no rotation here")


class _Unpicklable:
    def __reduce__(self) -> tuple:
        raise TypeError("not picklable")


@needs_fork
def test_the_value_comes_from_another_process_and_equals_the_one_here() -> None:
    pid, there = fork_call(_values)()
    _, here = fork_call(_values, fork=False)()
    assert pid != os.getpid()  # computed in the child
    np.testing.assert_array_equal(there, here)
    assert there.tobytes() == here.tobytes()


@needs_fork
@pytest.mark.parametrize("fork", [True, False])
def test_an_error_is_raised_when_the_value_is_asked_for(fork: bool) -> None:
    wait = fork_call(_refuse, fork=fork)  # no error yet
    with pytest.raises(GeometryError, match="no rotation here"):
        wait()


@needs_fork
def test_a_result_that_does_not_pickle_is_one_line_error() -> None:
    with pytest.raises(DetectionError, match="forked computation's result"):
        fork_call(_Unpicklable)()


@needs_fork
def test_a_child_that_dies_is_a_detection_error_not_a_hang() -> None:
    with pytest.raises(DetectionError, match="ended without its result"):
        fork_call(lambda: os._exit(3))()
