"""
Real-time scheduling for free_run (im_common/realtime.py).

Every thread of the process moves to SCHED_FIFO, or the refusal says what to grant; the process can
go back. Run in a child process so the test runner's own scheduling never changes.
"""
import subprocess
import sys

import pytest

_CHILD = """
import os, threading, time
from im_common import realtime
stop = threading.Event()
t = threading.Thread(target=stop.wait)          # a thread that exists before the switch
t.start()
ok, text = realtime.enter(12)
policies = {int(tid): os.sched_getscheduler(int(tid)) for tid in os.listdir('/proc/self/task')}
late = []
t2 = threading.Thread(target=lambda: late.append(os.sched_getscheduler(0)))  # made afterwards
t2.start(); t2.join()
print(ok, text, sorted(set(policies.values())), late, realtime.describe())
realtime.leave()
print(realtime.describe())
stop.set(); t.join()
"""


@pytest.mark.processes
def test_enter_moves_every_thread_or_says_what_to_grant():
    r = subprocess.run([sys.executable, '-c', _CHILD], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    first, second = r.stdout.splitlines()
    import os
    if first.startswith('True'):
        fifo = str(os.SCHED_FIFO)
        assert first == f'True fifo:12 [{fifo}] [{fifo}] fifo:12', first
        assert second == 'normal'
    else:                               # not allowed here: the reason names what to grant
        assert 'CAP_SYS_NICE' in first and 'rtprio' in first and second == 'normal'


def test_a_priority_outside_1_to_99_is_refused_by_value():
    from im_common import realtime
    assert realtime.enter(0) == (False, 'real-time priority 0 is outside 1..99')
    assert realtime.describe() == 'normal'
