"""
The run protocol's decisions: the run a node follows, its events, its end, its watchdog.

Which run a node follows, which events concern it, when its part of the run is over, and how long
its watchdog waits.

ROS-free (unit-tested without rclpy in ``tests/test_lockstep_parts.py``):
:class:`im_common.lockstep.LockstepNode` publishes and receives the events on ``/im/status`` and
asks a :class:`RunProtocol` what they mean.

Run protocol (``/im/status``, one ``diagnostic_msgs/DiagnosticArray`` per event):
- *startup*: each node publishes ``waiting`` and, once every one of its inputs has a publisher in
  the graph, ``ready``. The plant (time master) publishes step 0 only when every node of its
  ``wait_for`` list is ready, logging who is missing while it waits.
- *running*: a node on the critical path (``exact`` gate) that waits longer than
  ``input_timeout`` for an input reports the topic and stamp and stops with exit code 1. A node off
  the critical path (``follow`` gate: the adapter when nobody uses its estimates, any node when the
  plant runs in ``free_run``) never dies from being late: it takes what arrives, skips the steps it
  lost, and counts them.
- *lossless followers* (the recorder) announce themselves; the plant then stays within
  ``follower_window`` steps of the last step they acknowledged on ``/im/progress``, so their
  history can never overflow.
- *end*: the plant publishes ``finished`` after its last step; every other node waits for it after
  its own last step, so no node exits while its last message is still needed. Before a node exits
  it waits until its reliable publishers' data has been acknowledged.
- *stop*: SIGINT/SIGTERM/SIGHUP make a node publish ``stopping`` and exit 0. A node whose input
  provider stops or fails ends its part of the run cleanly (``stopped``, exit 0); the plant's
  ``stopped``/``failed``/``finished`` ends every node.
"""
from __future__ import annotations

from typing import Dict, List, Optional, Tuple

# Run states published on /im/status.
WAITING, READY, RUNNING, FINISHING = 'waiting', 'ready', 'running', 'finishing'
PARAMETERS, WARNING = 'parameters', 'warning'
#: Events for people and the recording, not states: they never change a node's state as its
#: peers see it (a warning after 'ready' does not undo it).
NOT_STATES = (PARAMETERS, WARNING)
FINISHED, STOPPING, STOPPED, FAILED = 'finished', 'stopping', 'stopped', 'failed'
END_STATES = (FINISHED, STOPPED, FAILED)
#: States of a provider that end the part of the run of a critical node reading it.
PROVIDER_GONE = (STOPPING, FAILED, STOPPED)


def is_master(values: dict) -> bool:
    """Tell whether the event is the time master's (the plant's)."""
    return values.get('time_master') == 'true'


class RunProtocol:
    """
    One node's view of the run: the run it follows, its time master's last state, its peers.

    ``run_id`` is the time master's run this node follows ('' until it has seen one);
    ``masters`` the last state of every time master of this graph's key seen (run id -> state);
    ``locked`` is set once the followed run is running (no other run is adopted from then on);
    ``peers`` the last event of every other node of the run (name -> (state, values));
    ``providers`` the nodes publishing this node's inputs (name -> one topic it provides).
    """

    __slots__ = ('run_id', 'masters', 'locked', 'master_state', 'peers', 'providers')

    def __init__(self, run_id: str = ''):
        self.run_id = run_id
        self.masters: Dict[str, str] = {}
        self.locked = False
        self.master_state = ''
        self.peers: Dict[str, tuple] = {}
        self.providers: Dict[str, str] = {}

    def event_values(self, critical: bool, time_master: bool, period: int, ns: int,
                     values: dict) -> dict:
        """
        Return the key/values of this node's event stamped ``ns``.

        They are its role, period, step and run, then ``values``.
        """
        base = {'role': 'critical' if critical else 'follower',
                'T_s_ns': period, 'step': ns // period if period else 0}
        if time_master:
            base['time_master'] = 'true'
        base['run_id'] = self.run_id
        base.update(values)
        return base

    def accept(self, own_name: str, name: str, state: str, values: dict) -> bool:
        """
        Tell whether a (verified) event concerns this node; a peer's is remembered in ``peers``.

        Ignored: this node's own events, the events that are not states, and the events of
        nodes that follow another run of the same key.
        """
        if name == own_name and values.get('run_id', '') == self.run_id:
            return False
        if state in NOT_STATES:
            return False
        master = is_master(values)
        if not master and values.get('run_id') and self.run_id \
                and values['run_id'] != self.run_id:
            return False
        if not master:
            self.peers[name] = (state, values)
        return True

    def master_event(self, state: str, run: str) -> Tuple[Optional[str], bool]:
        """
        Take a time master's event: return (the run to adopt now or None, whether to lock on it).

        The run followed is the one running, else the latest one waiting to start; once the
        followed run is running the choice is final.
        """
        if not run or self.locked:
            return None, False
        self.masters[run] = state
        live = [r for r, st in self.masters.items() if st not in END_STATES]
        running = [r for r in live if self.masters[r] == RUNNING]
        if running:                         # follow the run that started
            return running[0], True
        if live and self.run_id not in live:    # the latest time master waiting to start
            return live[-1], False
        if not live and not self.run_id:
            return run, False               # its end is news for this node too
        return None, False

    def other_live_runs(self) -> List[str]:
        """Return the runs of time masters not ended that this node does not follow (yet)."""
        return [r for r, st in self.masters.items() if st not in END_STATES and r != self.run_id]

    def end_of_part(self, name: str, state: str, values: dict, own_state: str, following: bool,
                    critical: bool) -> Optional[Tuple[str, bool]]:
        """
        Tell whether another node's event ends this node's part: (reason, notify) or None.

        The time master's end ends it (its ``finished`` only once this node finished its
        own last step, or follows); a provider of a critical node stopping or failing ends it
        too, and this node then says ``stopped`` (notify).
        """
        why = f" ({values['reason']})" if values.get('reason') else ''
        if is_master(values) and state in END_STATES:
            if state != FINISHED or own_state == FINISHING or following:
                return f'run ended by {name}: {state}' + why, False
            return None
        if state in PROVIDER_GONE and name in self.providers and critical:
            return f"input provider '{name}' {state}" + why, True
        return None


def watchdog_limit(state: str, timeout: float, startup_timeout: float,
                   time_master: bool) -> float:
    """
    Return how long [wall s] an exact gate may wait for its expected step before it is a fault.

    That is ``input_timeout`` while running (before step 0 at least the startup timeout); a node
    that is not the time master waits 1.5× + 1 s, so the time master diagnoses a stalled run first.
    """
    limit = timeout if state == RUNNING else max(timeout, startup_timeout)
    if not time_master:
        limit = 1.5 * limit + 1.0
    return limit


class WaitClock:
    """
    How long a gate has waited for its expected step, counted while this process could run.

    Advanced by the node's watchdog tick (every ``tick`` s): each tick adds the wall time since
    the previous one, but at most ``CAP_TICKS`` ticks' worth. A process starved of the CPU (a
    loaded machine: one run in one process stopped at 15.8 steps/s with "no /im/command/voltage
    stamped 0.114 s ... within 5.0 s of wall time") sees its ticks come late, and the time it did
    not run does not count: the command was not lost, its delivery thread had not run yet. A
    stalled run (a node gone, a message lost) keeps the ticks on time, and times out as before.
    """

    CAP_TICKS = 2.0

    __slots__ = ('cap', '_since', '_last', '_waited')

    def __init__(self, tick: float):
        self.cap = self.CAP_TICKS * float(tick)
        self._since = self._last = None
        self._waited = 0.0

    def waited(self, since: float, now: float) -> float:
        """Return the wait [s] for the step expected since ``since`` (monotonic), as of ``now``."""
        if since != self._since:            # a new step is expected: its wait starts at since
            self._since, self._last, self._waited = since, since, 0.0
        if now > self._last:
            self._waited += min(now - self._last, self.cap)
            self._last = now
        return self._waited
