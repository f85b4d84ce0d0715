"""The depth sweep's compiled kernels run on the threads its background threads leave, numba's setting restored after."""

from __future__ import annotations

import numba
import pytest

from labctl.kernel_threads import kernel_threads_beside


def test_fewer_threads_inside_at_least_one_the_setting_restored_after() -> None:
    before = numba.get_num_threads()
    with kernel_threads_beside(1) as inside:
        assert inside == numba.get_num_threads() == max(1, before - 1)
    assert numba.get_num_threads() == before
    with kernel_threads_beside(before + 5) as inside:
        assert inside == numba.get_num_threads() == 1
    assert numba.get_num_threads() == before


def test_as_a_decorator_and_through_an_exception() -> None:
    before = numba.get_num_threads()

    @kernel_threads_beside(before)
    def threads() -> int:
        return numba.get_num_threads()

    @kernel_threads_beside(before)
    def fails() -> None:
        raise RuntimeError("inside")

    assert threads() == 1
    with pytest.raises(RuntimeError):
        fails()
    assert numba.get_num_threads() == before
