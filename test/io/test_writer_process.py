"""The recorders' writer process (pcv_sim.io.writer_process): the same bag as a writer thread, a
writer that dies is reported and never blocks the loop, a node that dies leaves a finalized bag.

Real processes and real MCAP files, read back with the `mcap` package's reader.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from pcv_sim.device.recording import BagLayout, DeviceRecorder
from pcv_sim.errors import BagError
from pcv_sim.io import read_bag
from pcv_sim.io.recorder import WriterSettings
from pcv_sim.io.writer_process import HIGH_WATER, LOW_WATER

T0 = 1_700_000_000_000_000_000
DT = 100_000


def signals(k: int, duty: float = 0.5) -> dict[str, float]:
    return {"duty_command": duty, "duty": duty, "load_flow": 0.0, "supply_pressure": 200e5,
            "pressure": 1e5 + k, "current": 1e-3 * k, "spool_position": 1e-9 * k}


def feed(rec: DeviceRecorder, first: int, last: int) -> None:
    if first == 0:
        rec.start(T0, signals(0))
        first = 1
    for k in range(first, last + 1):
        rec(T0 + k * DT, signals(k, 0.5 if k < 3000 else 0.8))


def messages(bag: Path) -> list[tuple[str, int, bytes]]:
    """Every message of the bag (topic, log time, CDR bytes), by the mcap package's reader."""
    out = []
    for f in sorted(bag.glob("*.mcap")):
        with open(f, "rb") as fh:
            for _schema, channel, message in make_reader(fh).iter_messages(log_time_order=False):
                out.append((channel.topic, message.log_time, bytes(message.data)))
    return sorted(out)


def test_the_process_writes_the_messages_a_thread_writes(tmp_path: Path, emulator_recorder) -> None:
    for writer in ("process", "thread"):
        rec = emulator_recorder(tmp_path, name=writer, every=1, frame_id="load_port", writing=WriterSettings(writer=writer))
        feed(rec, 0, 6000)
        st = rec.close()
        assert (st.state, st.dropped, st.queued, st.messages) == ("closed", 0, 0, 4 + 3 * 6001), st
    assert messages(tmp_path / "process") == messages(tmp_path / "thread")
    assert read_bag(tmp_path / "process").closed_cleanly


def test_the_rig_recorder_runs_in_the_process_too(tmp_path: Path) -> None:
    layout = BagLayout.of_names(
        ["left"], ["left.pressure", "left.current", "left.spool_position", "cylinder.position", "cylinder.velocity",
                   "cylinder.effort"], ["left.duty_cycle", "left.supply_pressure", "cylinder.external_force"],
        namespace="/rig", chambers={"left": "a"})
    for writer in ("process", "inline"):
        rec = DeviceRecorder(tmp_path, layout, name=writer, writing=WriterSettings(writer=writer))
        rec.start(T0, {"left.duty_cycle": 0.5, "left.supply_pressure": 200e5, "cylinder.external_force": 0.0})
        for k in range(1, 500):
            rec.sample(T0 + k * 10 * DT, [1e6 + k, 0.5, 1e-4, 0.01 * k, 0.1, 5.0], [1e-6 * k])
            if k == 250:
                rec.text(rec.events_topic, T0 + k * 10 * DT, "fault injected")
        assert rec.close().state == "closed"
    assert messages(tmp_path / "process") == messages(tmp_path / "inline")


def test_a_writer_that_dies_is_reported_and_never_blocks_the_loop(tmp_path: Path, emulator_recorder) -> None:
    rec = emulator_recorder(tmp_path, name="b", every=1, writing=WriterSettings(writer="process"))
    feed(rec, 0, 1000)
    assert rec._proc is not None
    rec._proc.proc.kill()
    rec._proc.proc.wait()
    t = time.monotonic()
    feed(rec, 1001, 3000)                                  # batches go nowhere: counted, not waited for
    st = rec.status()
    assert st.state == "failed" and "writer process exited unexpectedly" in st.error, st
    assert st.dropped > 0
    st = rec.close()
    assert time.monotonic() - t < 5.0
    assert st.state == "failed" and st.dropped >= 3 * 1000


def test_when_full_wait_stops_waiting_for_a_dead_writer(tmp_path: Path, emulator_recorder) -> None:
    rec = emulator_recorder(tmp_path, name="b", every=1, max_queue_s=0.01,
                      writing=WriterSettings(writer="process", when_full="wait"))
    assert rec._proc is not None
    rec._proc.proc.send_signal(signal.SIGSTOP)            # a writer that stopped taking
    try:
        feed(rec, 0, 400)                                 # more than the ring holds: waits (0.02 s batches)
        rec._proc.proc.kill()
        t = time.monotonic()
        feed(rec, 401, 800)
        assert time.monotonic() - t < 5.0
    finally:
        rec._proc.proc.kill()
    assert rec.close().state == "failed"


def test_an_error_opening_the_bag_in_the_process_is_the_constructor_s(tmp_path: Path, emulator_recorder) -> None:
    with pytest.raises(BagError, match=r"the bag writer process could not start: .*ros_distro"):
        emulator_recorder(tmp_path, name="b", writing=WriterSettings(writer="process", ros_distro="no such distro!"))


def test_a_node_killed_by_sigkill_leaves_a_finalized_bag_with_every_batch_it_handed_over(tmp_path: Path) -> None:
    """The writer sees the control pipe close, writes what the ring holds and finalizes the bag."""
    script = textwrap.dedent(f"""
        import os, signal, sys, time
        sys.path[:0] = [{str(Path(__file__).parent)!r}, {str(Path(__file__).parents[1])!r}]
        from test_writer_process import feed
        from conftest import make_emulator_recorder
        from pcv_sim.io.recorder import WriterSettings
        rec = make_emulator_recorder({str(tmp_path)!r}, name="b", every=1, writing=WriterSettings(writer="process"))
        feed(rec, 0, 5000)
        time.sleep(rec.batch_period)
        rec.status()                       # hands over the batch in progress
        print(rec._proc.proc.pid, rec._proc.shipped, flush=True)
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    writer_pid, shipped = map(int, proc.stdout.split())
    assert shipped == 4 + 5001                             # start(): 3 inputs, outputs; 5000 samples, a duty change
    end = time.monotonic() + 60
    while _alive(writer_pid) and time.monotonic() < end:
        time.sleep(0.05)
    assert not _alive(writer_pid)
    bag = read_bag(tmp_path / "b")
    assert bag.closed_cleanly and not bag.warnings, bag.warnings
    assert len(bag["/pressure"]) == 5001 and len(bag["/duty_cycle"]) == 2


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_the_writer_process_ignores_sigint(tmp_path: Path, emulator_recorder) -> None:
    """A Ctrl-C reaches the node, which closes the bag after its last samples; the writer waits for it."""
    rec = emulator_recorder(tmp_path, name="b", every=1, writing=WriterSettings(writer="process"))
    feed(rec, 0, 100)
    assert rec._proc is not None
    os.kill(rec._proc.proc.pid, signal.SIGINT)
    time.sleep(0.2)
    feed(rec, 101, 200)
    st = rec.close()
    assert (st.state, st.dropped) == ("closed", 0)
    assert len(read_bag(tmp_path / "b")["/pressure"]) == 201


def _threads(pid: int) -> dict[int, int]:
    """Scheduling policy of every thread of process `pid`, by thread id."""
    out = {}
    for tid in map(int, os.listdir(f"/proc/{pid}/task")):
        with contextlib.suppress(ProcessLookupError):
            out[tid] = os.sched_getscheduler(tid)
    return out


def _autogroup(pid: int | str) -> str | None:
    """The autogroup's name, or None where the kernel keeps none (the file can exist and read
    empty: autogroups off, or a container that hides them)."""
    try:
        with open(f"/proc/{pid}/autogroup") as f:
            fields = f.read().split()
    except OSError:
        return None
    return fields[0] if fields else None


def test_the_writer_shares_the_node_s_scheduling_group_and_writes_only_on_idle_cpu(tmp_path: Path, emulator_recorder) -> None:
    """A session of its own would be an autogroup of its own, weighing as much as the node's whole
    group; in the node's session its writing thread runs under SCHED_IDLE (any thread that wants
    the CPU preempts it), its main thread (close, a filling ring) at normal priority."""
    rec = emulator_recorder(tmp_path, name="b", every=1, writing=WriterSettings(writer="process"))
    try:
        assert rec._proc is not None
        pid = rec._proc.proc.pid
        assert os.getsid(pid) == os.getsid(0)
        assert os.getpgid(pid) == pid != os.getpgid(0)       # its own process group: a Ctrl-C is the node's
        if _autogroup("self") is not None:
            assert _autogroup(pid) == _autogroup("self")
        end = time.monotonic() + 10
        while os.SCHED_IDLE not in _threads(pid).values() and time.monotonic() < end:
            time.sleep(0.01)
        policies = _threads(pid)
        assert policies.pop(pid) == os.SCHED_OTHER, policies
        assert list(policies.values()).count(os.SCHED_IDLE) == 1, policies
    finally:
        rec.close()


def test_under_cpu_load_the_ring_keeps_every_batch_until_close(tmp_path: Path, cpu_load, emulator_recorder) -> None:
    """Two CPU burners in this session: the idle writer falls behind (how far depends on how often
    a core idles between the burners' slices: not asserted), the ring holds what the loop handed
    over, and closing (at normal priority) writes all of it."""
    rec = emulator_recorder(tmp_path, name="b", every=1, writing=WriterSettings(writer="process"))
    assert rec._proc is not None
    feed(rec, 0, 20_000)                                   # 2 s of 10 kHz samples, ~1 MB in the ring
    time.sleep(rec.batch_period)
    rec.status()                                           # hands over the batch in progress
    assert rec._proc.shipped == 4 + 20_001
    time.sleep(1.0)
    st = rec.status()
    assert (st.state, st.dropped) == ("recording", 0)
    for h in cpu_load:
        h.kill()
    st = rec.close()
    assert (st.state, st.dropped, st.messages) == ("closed", 0, 4 + 3 * 20_001), st
    assert len(read_bag(tmp_path / "b")["/pressure"]) == 20_001


def test_a_ring_filled_past_half_is_written_by_the_normal_priority_thread_under_cpu_load(tmp_path: Path,
                                                                                          cpu_load, emulator_recorder) -> None:
    """Beside two burners the idle writer gets little; once the ring is more than HIGH_WATER full
    the process's main thread (normal priority) writes it down to LOW_WATER, so a long busy spell
    costs no data while the ring has room. Nothing is dropped, all is written. (Which thread wrote
    is not asserted: the idle one gets CPU whenever a core idles between the burners' slices.)"""
    rec = emulator_recorder(tmp_path, name="b", every=1, max_queue_s=3.0, writing=WriterSettings(writer="process"))
    assert rec._proc is not None
    ring = rec._proc.ring
    feed(rec, 0, 0)
    n = 0
    while ring.used() <= HIGH_WATER * ring.capacity:      # as fast as this side can: past half within ~0.3 s
        feed(rec, n + 1, n + 1000)
        n += 1000
        rec._ship()
    end = time.monotonic() + 60
    while ring.used() > LOW_WATER * ring.capacity and time.monotonic() < end:
        time.sleep(0.05)
    assert ring.used() <= LOW_WATER * ring.capacity, f"{ring.used()} of {ring.capacity} bytes still waiting"
    st = rec.close()
    assert (st.state, st.dropped, st.messages) == ("closed", 0, 4 + 3 * (n + 1) - (n < 3000) * 1), st


def test_a_full_ring_drops_whole_batches_and_counts_every_message(tmp_path: Path, emulator_recorder) -> None:
    """A writer that takes nothing (stopped): batches that do not fit are counted as dropped, the
    ones that fit are written at close: bag + dropped = everything recorded."""
    rec = emulator_recorder(tmp_path, name="b", every=1, max_queue_s=0.05, writing=WriterSettings(writer="process"))
    assert rec._proc is not None
    rec._proc.proc.send_signal(signal.SIGSTOP)
    try:
        feed(rec, 0, 5000)
        time.sleep(rec.batch_period)
        st = rec.status()
        assert st.dropped > 0 and st.state == "recording", st
    finally:
        rec._proc.proc.send_signal(signal.SIGCONT)
    st = rec.close()
    assert st.state == "closed" and st.messages > 0, st
    assert st.messages + st.dropped == 4 + 3 * 5001, st
    bag = read_bag(tmp_path / "b")
    assert sum(len(bag[t]) for t in bag.topics) == st.messages


def test_a_writer_that_is_alive_but_takes_nothing_does_not_hold_up_the_close(tmp_path: Path, emulator_recorder) -> None:
    """The writer process stopped (alive, taking nothing) with its ring full: the loop's waiting
    (`when_full: wait`) and the close each give up after `stall_timeout` s without progress, count
    what they could not hand over as dropped and say why; nothing waits forever."""
    rec = emulator_recorder(tmp_path, name="b", every=1, max_queue_s=0.01,
                            writing=WriterSettings(writer="process", when_full="wait", stall_timeout=1.0))
    assert rec._proc is not None
    rec._proc.proc.send_signal(signal.SIGSTOP)
    try:
        t = time.monotonic()
        feed(rec, 0, 3000)                                # more than the 64 KiB ring holds: waits, then gives up
        fed = time.monotonic() - t
        t = time.monotonic()
        st = rec.close()
        closed = time.monotonic() - t
    finally:
        rec._proc.proc.send_signal(signal.SIGCONT)
        rec._proc.proc.kill()
    assert fed < 1.0 + 5.0 and closed < 2 * 1.0 + 5.0, (fed, closed)
    assert st.state == "failed" and "took nothing for 1 s" in st.error and st.dropped > 0, st


def test_a_writer_thread_stuck_in_a_write_does_not_hold_up_the_close(tmp_path: Path, emulator_recorder,
                                                                      monkeypatch) -> None:
    """The thread writer (not the nodes'): a write that never returns (a disk that hangs) is given
    `stall_timeout` s at the close, then the bag is reported failed rather than waited for."""
    import threading

    rec = emulator_recorder(tmp_path, name="b", every=1, writing=WriterSettings(writer="thread", stall_timeout=0.5))
    hang = threading.Event()
    monkeypatch.setattr(rec, "_write_batch", lambda items: hang.wait())
    try:
        feed(rec, 0, 100)
        time.sleep(3 * rec.batch_period)                  # the writer thread is in its write
        t = time.monotonic()
        st = rec.close()
        assert time.monotonic() - t < 0.5 + 2.0
    finally:
        hang.set()
    assert st.state == "failed" and "did not finish within 0.5 s" in st.error, st


def test_taking_over_from_a_starved_idle_writer_thread_does_not_wait_for_idle_cpu(cpu_load) -> None:
    """Priority inversion at close: the background writer thread (SCHED_IDLE) holds the lock the
    main thread needs (a record in progress) and, beside two CPU burners, gets a slice only now and
    then: 0.2 s of its CPU then took ~a minute, and closing a recording beside four burners 1.5-42 s
    (a third of the bags killed unfinished after STALL_TIMEOUT). The main thread raises it while it
    waits, where the process may: the lock comes within seconds."""
    import threading

    from pcv_sim.io.writer_process import Ring, _set_policy, _Turns

    allowed = []

    def try_policy() -> None:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
        allowed.append(_set_policy(threading.get_native_id(), os.SCHED_OTHER))

    t = threading.Thread(target=try_policy)
    t.start()
    t.join()
    if not allowed[0]:
        pytest.skip("this process may not raise a SCHED_IDLE thread back to normal priority")
    ring = Ring.create(1 << 16)
    turns = _Turns(ring, rec=None)
    holding = threading.Event()

    def starved_record() -> None:              # the background thread's part: SCHED_IDLE, `work` held
        turns.tid = threading.get_native_id()
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
        with turns.work:
            holding.set()
            end = time.thread_time() + 0.2    # 0.2 s of its own CPU: a slow record
            while time.thread_time() < end:
                pass

    worker = threading.Thread(target=starved_record, daemon=True)
    worker.start()
    assert holding.wait(60)
    t0 = time.monotonic()
    turns.take_over(until=1)                  # the ring is empty: only the lock is waited for
    took = time.monotonic() - t0
    ring.close()
    assert took < 10.0, f"the main thread waited {took:.1f} s for the idle thread's lock"
