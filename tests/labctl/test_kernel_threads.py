"""The compiled kernels run on the threads labctl's background threads leave, or on one; numba's setting restored after."""

from __future__ import annotations

import numba
import pytest

from labctl.kernel_threads import kernel_threads_beside, serial_kernels


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


def test_serial_kernels_run_on_one_thread_and_restore_the_setting() -> None:
    before = numba.get_num_threads()
    with serial_kernels() as inside:
        assert inside == numba.get_num_threads() == 1
    assert numba.get_num_threads() == before
    with pytest.raises(RuntimeError), serial_kernels():
        raise RuntimeError("inside")
    assert numba.get_num_threads() == before
