import asyncio
import threading

from companion.latest import Latest


def test_get_before_and_after_publish():
    slot: Latest[int] = Latest()
    assert slot.get() is None and slot.version == 0
    assert slot.publish(5) == 1
    assert slot.get().value == 5 and slot.version == 1


def test_thread_publish_wakes_async_waiter():
    slot: Latest[str] = Latest()

    async def main():
        waiter = asyncio.create_task(slot.wait_newer(0, timeout=5))
        await asyncio.sleep(0.05)
        threading.Thread(target=slot.publish, args=("hello",)).start()
        got = await waiter
        return got

    got = asyncio.run(main())
    assert got.value == "hello" and got.version == 1


def test_slow_consumer_skips_to_newest():
    slot: Latest[int] = Latest()
    for i in range(100):
        slot.publish(i)

    got = asyncio.run(slot.wait_newer(3, timeout=1))
    assert got.value == 99 and got.version == 100


def test_timeout_returns_current_and_does_not_leak_waiters():
    slot: Latest[int] = Latest(1)

    async def main():
        for _ in range(50):
            got = await slot.wait_newer(1, timeout=0.001)
            assert got.version == 1
        return len(slot._waiters)

    assert asyncio.run(main()) == 0


def test_close_releases_waiters():
    slot: Latest[int] = Latest()

    async def main():
        waiter = asyncio.create_task(slot.wait_newer(0))
        await asyncio.sleep(0.02)
        slot.close()
        return await asyncio.wait_for(waiter, 1)

    assert asyncio.run(main()) is None


def test_a_publish_listener_sees_every_value_in_the_publishers_thread():
    slot: Latest[int] = Latest()
    seen: list[tuple[int, str]] = []

    def listener(v: int) -> None:
        seen.append((v, threading.current_thread().name))

    slot.add_listener(listener)
    t = threading.Thread(target=lambda: [slot.publish(i) for i in range(100)], name="producer")
    t.start()
    t.join()
    slot.remove_listener(listener)
    slot.publish(100)
    assert seen == [(i, "producer") for i in range(100)]
