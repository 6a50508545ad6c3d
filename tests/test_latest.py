import asyncio
import threading

from fpv_station.companion.latest import Latest, Wakeup


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


def test_a_wakeup_from_another_thread_is_not_missed():
    """Given before the wait (after the clear) it ends the wait at once; given during it,
    from a thread, it ends it with one hop to the loop; none given: the timeout."""

    wakeup = Wakeup()

    async def run() -> tuple[float, float, float]:
        loop = asyncio.get_running_loop()
        wakeup.clear()
        threading.Thread(target=wakeup.wake).start()
        await asyncio.sleep(0.1)  # woken while nobody waits: it stays set
        t0 = loop.time()
        await wakeup.wait(5.0)
        before = loop.time() - t0
        wakeup.clear()
        threading.Timer(0.2, wakeup.wake).start()
        t0 = loop.time()
        await wakeup.wait(5.0)
        during = loop.time() - t0
        wakeup.clear()
        t0 = loop.time()
        await wakeup.wait(0.2)
        return before, during, loop.time() - t0

    before, during, none = asyncio.run(run())
    assert before < 1.0 and during < 4.0  # not the 5 s timeout
    assert none >= 0.15


def test_a_bound_method_listener_is_removed_by_the_same_expression():
    class Owner:
        def __init__(self) -> None:
            self.seen: list[int] = []

        def note(self, value: int) -> None:
            self.seen.append(value)

    slot: Latest[int] = Latest()
    owner = Owner()
    slot.add_listener(owner.note)
    slot.publish(1)
    slot.remove_listener(owner.note)  # a new bound method object, equal to the added one
    slot.publish(2)
    assert owner.seen == [1]
