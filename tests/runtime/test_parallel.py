"""The helper thread runs callables at once, returns their results in order, raises their errors
only once every one has ended, and stops on close."""

import threading

import pytest

from evp.runtime.parallel import HelperThreads

WAIT_S = 30.0  # an upper bound for a thread to reach an event, never a delay


def _helper_threads() -> list[threading.Thread]:
    return [thread for thread in threading.enumerate() if thread.name.startswith("evp-helper")]


@pytest.fixture
def helper():
    threads = HelperThreads()
    yield threads
    threads.close()


def test_runs_the_callables_at_once_and_returns_their_results_in_order(helper):
    first_running, second_running = threading.Event(), threading.Event()

    def first():
        first_running.set()
        return second_running.wait(WAIT_S), threading.current_thread().name

    def second():
        second_running.set()
        return first_running.wait(WAIT_S), threading.current_thread().name

    (first_met, first_thread), (second_met, second_thread) = helper(first, second)
    assert first_met and second_met  # each saw the other running: one after the other, both waits would time out
    assert first_thread.startswith("evp-helper") and second_thread == threading.current_thread().name
    assert helper(lambda: 1, lambda: 2, lambda: 3) == [1, 2, 3]  # more callables than helpers: queued


def test_an_error_comes_back_only_once_every_callable_has_ended(helper):
    release, ended = threading.Event(), threading.Event()

    def slow():
        assert release.wait(WAIT_S)
        ended.set()

    def failing():
        release.set()
        raise ValueError("in the caller's thread")

    with pytest.raises(ValueError, match="caller's thread"):
        helper(slow, failing)
    assert ended.is_set()

    def failing_in_helper():
        raise ValueError("in the helper")

    with pytest.raises(ValueError, match="in the helper"):
        helper(failing_in_helper, lambda: None)


def test_close_leaves_no_thread_alive():
    threads = HelperThreads()
    threads(lambda: None, lambda: None)
    assert _helper_threads()
    threads.close()
    threads.close()  # idempotent
    assert not _helper_threads()
