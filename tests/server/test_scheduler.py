"""start_now runs a send in the caller when the transport takes it, in a task when it must wait."""

import asyncio
import concurrent.futures

import pytest

from server.scheduler import start_now


def run(main):
    """asyncio.run(main()) on a thread of its own: the worker's main thread may hold another
    loop (Playwright's, from the browser tests)."""
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, main()).result(timeout=30)


def test_a_coroutine_that_does_not_wait_completes_in_the_call():
    async def main():
        done = []

        async def send():
            done.append(1)

        assert start_now(send()) is None
        assert done == [1]

    run(main)


def test_a_coroutine_that_waits_finishes_in_a_task_with_its_result_seen_by_it():
    async def main():
        gate = asyncio.get_running_loop().create_future()
        seen = []

        async def send():
            seen.append(await gate)
            await asyncio.sleep(0)          # a bare yield on the way
            seen.append("after")

        task = start_now(send())
        assert isinstance(task, asyncio.Task) and seen == []
        gate.set_result("open")
        await asyncio.wait_for(task, 1.0)
        assert seen == ["open", "after"]

    run(main)


def test_errors_before_and_after_waiting_reach_the_caller():
    async def main():
        async def fails_at_once():
            raise ConnectionResetError("gone")

        with pytest.raises(ConnectionResetError):
            start_now(fails_at_once())

        gate = asyncio.get_running_loop().create_future()

        async def fails_later():
            await gate

        task = start_now(fails_later())
        gate.set_exception(ConnectionResetError("gone later"))
        with pytest.raises(ConnectionResetError, match="gone later"):
            await asyncio.wait_for(task, 1.0)

    run(main)


def test_cancelling_the_task_closes_the_waiting_coroutine():
    async def main():
        closed = []

        async def send():
            try:
                await asyncio.Event().wait()
            finally:
                closed.append(True)

        task = start_now(send())
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        assert closed == [True]

    run(main)
