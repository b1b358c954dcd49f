"""Reading ahead: the next input is prepared on a second thread, with the results and errors of doing it in order."""

import threading

import cv2
import numpy as np
import pytest

from ngp_kornia import calibrate
from ngp_kornia.errors import ImageReadError
from ngp_kornia.threads import Lookahead


def test_results_come_back_in_order_whatever_was_read_ahead():
    calls = []

    def square(k):
        calls.append(k)
        return k * k

    with Lookahead(square) as ahead:
        got = [ahead.get(k, k + 1 if k < 4 else None) for k in range(5)]
    assert got == [0, 1, 4, 9, 16]
    assert sorted(calls) == [0, 1, 2, 3, 4]  # each key computed once


def test_a_key_that_was_not_read_ahead_is_computed_on_the_spot():
    with Lookahead(lambda k: -k) as ahead:
        assert ahead.get(1, 2) == -1
        assert ahead.get(5) == -5  # not the pending 2: computed here
        assert ahead.get(2) == -2


def test_the_error_of_one_key_is_raised_when_that_key_is_asked_for():
    def fail_on_two(k):
        if k == 2:
            raise ValueError("two")
        return k

    with Lookahead(fail_on_two) as ahead:
        assert ahead.get(1, 2) == 1  # 2 fails in the background: not raised yet
        with pytest.raises(ValueError, match="two"):
            ahead.get(2, 3)
        assert ahead.get(3) == 3


def test_the_work_runs_on_another_thread_which_has_ended_after_close():
    names = {}

    def where(k):
        names[k] = threading.current_thread().name
        return k

    ahead = Lookahead(where)
    ahead.get(0, 1)
    ahead.get(1)
    ahead.close()
    assert names[0] == threading.current_thread().name and names[1].startswith("ngp-ahead")
    assert not any(t.name.startswith("ngp-ahead") for t in threading.enumerate())


def test_close_waits_for_a_running_computation():
    import time

    done = []

    def slow(k):
        time.sleep(0.1 if k == 0 else 0.5)
        done.append(k)
        return k

    ahead = Lookahead(slow)
    assert ahead.get(0, 1) == 0 and done == [0]  # 1 is still running in the background
    ahead.close()
    assert done == [0, 1]  # waited for: nothing runs on after close


def test_a_bad_file_in_a_list_is_reported_by_name_after_the_good_ones_were_read(tmp_path):
    good = tmp_path / "good.png"
    cv2.imwrite(str(good), np.full((64, 64, 3), 128, np.uint8))
    missing = tmp_path / "missing.jpg"
    with pytest.raises(ImageReadError, match="missing.jpg"):
        calibrate([good, good, missing], weights="none")
