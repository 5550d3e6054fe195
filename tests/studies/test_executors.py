"""The local pool's bookkeeping when a worker dies: deterministic, on a fake pool.

The real processes are in ``test_campaign_processes.py``; here the pool is a stand-in whose
timing is chosen, so the race seen there (the pool breaks between a finished task and the next
submit: ``submit`` raises ``BrokenProcessPool``) happens every time.
"""

import concurrent.futures
from concurrent.futures.process import BrokenProcessPool

from uuv_ocp.studies.executors import TaskRunner


class RacingPool:
    """Pool 1: runs the first task, holds the second, breaks when the third is submitted."""

    def __init__(self):
        self.submitted, self.held = 0, None

    def submit(self, function, *args):
        self.submitted += 1
        future = concurrent.futures.Future()
        if self.submitted == 1:
            future.set_result(function(*args))
        elif self.submitted == 2:
            self.held = future  # its worker dies: the future learns it a little later
        else:
            self.held.set_exception(BrokenProcessPool("a child process terminated abruptly"))
            raise BrokenProcessPool("a child process terminated abruptly")
        return future

    def shutdown(self, wait=True, cancel_futures=False):
        pass


class SoundPool:
    """The restarted pool: runs each task at once."""

    def submit(self, function, *args):
        future = concurrent.futures.Future()
        future.set_result(function(*args))
        return future

    def shutdown(self, wait=True, cancel_futures=False):
        pass


def test_a_pool_that_breaks_between_a_result_and_the_next_submit_is_restarted(monkeypatch):
    pools = iter([RacingPool(), SoundPool()])
    monkeypatch.setattr(TaskRunner, "_new_pool", lambda self: next(pools))
    restarts = []
    runner = TaskRunner("local", 2, on_restart=lambda message, keys: restarts.append(keys))
    runner._pool = runner._new_pool()  # what __enter__ does for workers > 1
    results = dict(runner._run_pool(lambda x: 10 * x, [("a", (1,)), ("b", (2,)), ("c", (3,))]))
    assert results == {"a": 10, "b": 20, "c": 30}  # every task ran; none given up
    assert restarts == [["b"]]  # only the task in flight when the pool broke is rerun
