"""send_now runs a send in the caller when the transport takes it, and abandons it when it would wait."""

import asyncio
import concurrent.futures

import pytest

from server.scheduler import send_now


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

        assert send_now(send()) is True
        assert done == [1]

    run(main)


def test_a_coroutine_that_would_wait_is_abandoned_and_closed():
    async def main():
        full = asyncio.Event()   # a transport above its high-water mark
        steps = []

        async def send():
            try:
                await full.wait()
                steps.append("written")
            finally:
                steps.append("closed")

        assert send_now(send()) is False
        assert steps == ["closed"]
        full.set()
        await asyncio.sleep(0.01)
        assert steps == ["closed"]   # nothing was left behind to write it later

    run(main)


def test_errors_reach_the_caller():
    async def main():
        async def fails_at_once():
            raise ConnectionResetError("gone")

        with pytest.raises(ConnectionResetError):
            send_now(fails_at_once())

    run(main)
