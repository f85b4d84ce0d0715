"""Resume and info on run files damaged after the fact: never a traceback; resume says what can be recovered
and `resume --into NEW.h5` continues the run in a new file with the readable complete steps, to the key figures
of an uninterrupted run."""

from __future__ import annotations

import os
import shutil

import h5py
import pytest

from labctl.cli import main
from labctl.evaluation.evaluate import evaluate_runs
from labctl.evaluation.keyfigures import clean

STEPS = [f"{i:05d}_{'offset_calibration' if i == 0 else 'depth_sweep'}" for i in range(6)]


def invoke(capsys, *args) -> tuple[int, str]:
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    return info.value.code, captured.err


def figures(run) -> dict:
    return {name: clean(f.value) for name, f in evaluate_runs([run]).figures.items()}


@pytest.fixture
def aborted_run(tmp_path, write_campaign, small_model, capsys):
    """A complete simulated run, its figures, and a copy marked aborted with its last two steps unfinished."""
    reference = tmp_path / "reference.h5"
    code, err = invoke(capsys, "run", write_campaign(), "--sim", "--model", small_model(), "-o", reference, "--quiet")
    assert code == 0, err
    run = tmp_path / "run.h5"
    shutil.copy(reference, run)
    with h5py.File(run, "r+") as f:
        f.attrs["status"] = "aborted"
        for step_id in STEPS[4:]:
            f["steps"][step_id].attrs["complete"] = False
    return run, figures(reference)


def chunk_of(path, step_id: str, channel: str = "z") -> tuple[int, int]:
    with h5py.File(path, "r") as f:
        chunk = f["steps"][step_id][channel].id.get_chunk_info(0)
        return chunk.byte_offset, chunk.size


def overwrite(path, offset: int, data: bytes) -> None:
    with open(path, "r+b") as f:
        f.seek(offset)
        f.write(data)


def test_an_unreadable_step_is_left_behind_and_run_again_in_the_new_file(aborted_run, tmp_path, capsys):
    run, expected = aborted_run
    offset, size = chunk_of(run, STEPS[2])
    overwrite(run, offset, os.urandom(size))  # a complete step's frame 0 no longer decompresses
    before = run.read_bytes()

    code, err = invoke(capsys, "info", run)
    assert code == 0, err
    new = tmp_path / "new.h5"
    code, err = invoke(capsys, "resume", run, "--into", new)
    assert code == 0, err
    assert f"3 complete step(s) can be recovered ({STEPS[0]} .. {STEPS[3]})" in err
    assert f"unreadable, to be run again: {STEPS[2]}" in err and f"the run continues in {new}" in err
    assert run.read_bytes() == before  # the damaged file is only read
    with h5py.File(new, "r") as f:
        assert f.attrs["status"] == "complete" and sorted(f["steps"]) == STEPS
    assert figures(new) == expected


def test_a_garbage_tail_does_not_stop_resume_in_place(aborted_run, capsys):
    run, expected = aborted_run
    with open(run, "ab") as f:
        f.write(os.urandom(100_000))
    code, err = invoke(capsys, "info", run)
    assert code == 0, err
    code, err = invoke(capsys, "resume", run, "--quiet")
    assert code == 0, err
    assert figures(run) == expected


def test_a_file_cut_short_gets_a_message_and_what_can_be_recovered(aborted_run, tmp_path, capsys):
    run, expected = aborted_run
    os.truncate(run, run.stat().st_size * 2 // 3)
    code, err = invoke(capsys, "info", run)
    assert code == 2 and str(run) in err
    code, err = invoke(capsys, "resume", run)
    assert code == 2 and f"{run} is damaged" in err and "truncated file" in err
    if "--into NEW.h5" in err:  # the header survived the cut: the readable steps carry over
        new = tmp_path / "new.h5"
        code, err = invoke(capsys, "resume", run, "--into", new, "--quiet")
        assert code == 0, err
        assert figures(new) == expected
    else:
        assert "nothing can be recovered" in err and "labctl run" in err


def test_a_destroyed_header_is_refused_with_a_message(aborted_run, tmp_path, capsys):
    run, _ = aborted_run
    overwrite(run, 0, os.urandom(4096))
    code, err = invoke(capsys, "info", run)
    assert code == 2 and str(run) in err
    code, err = invoke(capsys, "resume", run)
    assert code == 2 and f"{run} is damaged" in err and "nothing can be recovered" in err
    code, err = invoke(capsys, "resume", run, "--into", tmp_path / "new.h5")
    assert code == 2 and "nothing can be recovered" in err and not (tmp_path / "new.h5").exists()


def point_list_of_steps_past_the_end(path) -> None:
    """What a kill -9 in the middle of a flush that adds a step can leave: the /steps group's symbol table
    message (HDF5 object header v1, message type 0x11: B-tree address, local heap address) pointing its local
    heap past the end of the file, the block it was moved to never written. The header's messages are read
    from its first block and from the blocks its continuation messages (type 0x10: address, length) lead to."""
    with h5py.File(path, "r") as f:
        header = h5py.h5o.get_info(f["steps"].id).addr
    with open(path, "rb") as f:
        f.seek(header)
        prefix = f.read(16)
        blocks = [(header + 16, int.from_bytes(prefix[8:12], "little"))]  # after the 16-byte prefix of a v1 header
        while blocks:
            start, length = blocks.pop(0)
            f.seek(start)
            data = f.read(length)
            position = 0
            while position + 8 <= length:
                kind = int.from_bytes(data[position:position + 2], "little")
                size = int.from_bytes(data[position + 2:position + 4], "little")
                if kind == 0x11:
                    overwrite(path, start + position + 8 + 8, (os.path.getsize(path) + 2**20).to_bytes(8, "little"))
                    return
                if kind == 0x10:
                    body = data[position + 8:position + 8 + size]
                    blocks.append((int.from_bytes(body[:8], "little"), int.from_bytes(body[8:16], "little")))
                position += 8 + size
    raise AssertionError("no symbol table message in the header of /steps")


def test_a_list_of_steps_pointing_past_the_end_loses_no_committed_step(aborted_run, tmp_path, capsys):
    run, expected = aborted_run
    point_list_of_steps_past_the_end(run)
    with h5py.File(run, "r") as f, pytest.raises((OSError, KeyError, RuntimeError)):
        list(f["steps"])

    code, err = invoke(capsys, "resume", run)
    assert code == 2 and "--into NEW.h5" in err and f"4 complete step(s) can be recovered ({STEPS[0]} .. {STEPS[3]})" in err
    new = tmp_path / "new.h5"
    code, err = invoke(capsys, "resume", run, "--into", new)
    assert code == 0, err
    assert all(f"recovered {step_id}" in err for step_id in STEPS[:4]) and f"recovered {STEPS[4]}" not in err
    with h5py.File(run, "r") as damaged, h5py.File(new, "r") as f:
        assert f.attrs["status"] == "complete" and sorted(f["steps"]) == STEPS
        for i, step_id in enumerate(STEPS):  # the new file's index leads to every step
            assert f[f["step_index"][i]].name == f"/steps/{step_id}"
        for step_id in STEPS[:4]:  # carried over, not run again
            assert f["steps"][step_id].attrs["finished"] == damaged[damaged["step_index"][int(step_id[:5])]].attrs["finished"]
    assert figures(new) == expected


def test_a_file_without_a_step_index_still_reads_and_resumes(aborted_run, tmp_path, capsys):
    run, expected = aborted_run
    with h5py.File(run, "r+") as f:  # as written before the step index existed
        del f["step_index"]
    code, err = invoke(capsys, "info", run)
    assert code == 0, err
    code, err = invoke(capsys, "resume", run, "--quiet")
    assert code == 0, err
    assert figures(run) == expected

    point_list_of_steps_past_the_end(run)  # without the index, a lost list of steps loses the steps
    new = tmp_path / "new.h5"
    code, err = invoke(capsys, "resume", run, "--into", new)
    assert code == 0, err
    assert "no step can be recovered" in err and "recovered 0000" not in err
    with h5py.File(new, "r") as f:
        assert "step_index" not in f and sorted(f["steps"]) == STEPS
    assert figures(new) == expected
