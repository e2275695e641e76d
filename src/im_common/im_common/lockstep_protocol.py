"""
The run protocol's decisions: the run a node follows, its events, its end, its watchdog.

Which run a node follows, which events concern it, when its part of the run is over, and how long
its watchdog waits.

ROS-free (unit-tested without rclpy in ``tests/test_lockstep_parts.py``):
:class:`im_common.lockstep.LockstepNode` publishes and receives the events on ``/im/status`` and
asks a :class:`LockstepProtocol` what they mean.

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

from typing import Callable, Dict, Iterable, List, Optional, Sequence, Tuple

from .conversions import ns_to_s

# Run states published on /im/status.
WAITING, READY, RUNNING, FINISHING = 'waiting', 'ready', 'running', 'finishing'
#: A node's state before it announced anything (never published).
STARTING = 'starting'
#: The time master's state after its last step while its lossless followers catch up (never
#: published: it says ``finished`` once they acknowledged the last step).
DRAINING = 'draining'
#: A lossless follower's end of the run when the time master left the graph without a final event
#: (its last event lost, or killed): recorded as the run's end, never published.
ENDED = 'ended'
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


class LockstepProtocol:
    """
    One node's view of the run: the run it follows, its time master's last state, its peers.

    ``run_id`` is the time master's run this node follows ('' until it has seen one);
    ``masters`` the last state of every time master of this graph's key seen (run id -> state);
    ``locked`` is set once the followed run is running (no other run is adopted from then on);
    ``peers`` the last event of every other node of the run (name -> (state, values));
    ``providers`` the nodes publishing this node's inputs (name -> one topic it provides).
    """

    __slots__ = ('run_id', 'masters', 'locked', 'master_state', 'peers', 'providers',
                 'running_run', 'foreign_said')

    def __init__(self, run_id: str = ''):
        self.run_id = run_id
        self.masters: Dict[str, str] = {}
        self.locked = False
        self.master_state = ''
        self.peers: Dict[str, tuple] = {}
        self.providers: Dict[str, str] = {}
        self.running_run = ''           # the run whose 'running' was seen
        self.foreign_said = False

    def followed(self, state: str, values: dict) -> Tuple[bool, bool]:
        """
        Take an event of the followed run's time master: (free_run, first ``running`` of it).

        A free_run time master says so from its ``waiting`` on: a follower goes real-time then.
        """
        self.master_state = state
        first = state == RUNNING and self.running_run != self.run_id
        if first:
            self.running_run = self.run_id
        return values.get('mode') == 'free_run', first

    def first_foreign(self, run: str) -> bool:
        """Tell whether ``run``, of another time master of the key, is the first one to report."""
        if self.run_id and run != self.run_id and not self.foreign_said:
            self.foreign_said = True
            return True
        return False

    def foreign_text(self, name: str, run: str) -> str:
        """Say that events of another run's time master ``name`` are ignored."""
        return (f"ignoring '{name}' of another run ({run}) on this ROS domain; this node follows "
                f'run {self.run_id}')

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


# The roles ------------------------------------------------------------------------------------
#: What a time master does about a peer's event (:meth:`TimeMaster.on_peer`).
IGNORE, YIELD, JOINED, LEFT, STOP = 'ignore', 'yield', 'joined', 'left', 'stop'
#: The time master's states in which it takes commands (after them a command is too late).
MASTER_STEPPING = (RUNNING, DRAINING)


def yield_text(name: str, run: str, domain) -> str:
    """Say why a time master yields to another of the same key on its domain (one line)."""
    return (f"another plant ('{name}', run {run}) of this graph's key is on this ROS domain "
            f'(ROS_DOMAIN_ID={domain}): the nodes started by hand would not know which run to '
            f'follow — give each graph its own ROS_DOMAIN_ID or its own graph_key_file')


def _number(text) -> Optional[float]:
    try:
        return float(text)
    except (TypeError, ValueError):
        return None


class TimeMaster:
    """
    The time master's decisions (the plant): step 0, its lossless followers, its end, its rivals.

    ``wait_for``: the nodes that must be ready (for this run, at this ``period``) before step 0;
    ``window``: how many steps it may run ahead of the last step a lossless follower acknowledged
    (a follower silent for ``timeout`` s is dropped, ``on_dropped(name, acked_ns)``); ``others``:
    the last state of every other time master of its key seen (run -> (name, state, started_at));
    ``parked``: a complete step held back while a follower lags (:meth:`hold`, :meth:`resume`).
    A node calls it with what it saw (peers' events, acknowledgements, the monotonic time ``now``)
    and acts on what it answers; it does no I/O.
    """

    __slots__ = ('run_id', 'period', 'wait_for', 'window', 'timeout', 'domain', 'followers',
                 'others', 'started_at', 'parked', 'on_dropped')

    def __init__(self, run_id: str, period: int, wait_for: Sequence[str], window: int,
                 timeout: float = 5.0, domain=''):
        self.run_id = run_id
        self.period = int(period)
        self.wait_for = list(wait_for)
        self.window = int(window)
        self.timeout = float(timeout)
        self.domain = domain
        self.followers: Dict[str, list] = {}    # name -> [acked stamp ns, monotonic of last ack]
        self.others: Dict[str, tuple] = {}
        self.started_at: Optional[float] = None  # wall time of step 0 (which of two yields)
        self.parked = None
        self.on_dropped: Optional[Callable[[str, int], None]] = None

    # Step 0 -------------------------------------------------------------------------------
    def start_condition(self, peers: Dict[str, tuple]) -> Tuple[bool, Optional[str]]:
        """
        Tell whether step 0 may go now: (ok, the fault that ends the run instead, or None).

        It may when no other time master of the key is live and every node of ``wait_for`` is
        ready (or running) in this run; a node at another period is a fault.
        """
        for run, (name, state, _started) in self.others.items():
            if state not in END_STATES:
                return False, yield_text(name, run, self.domain)
        for name in self.wait_for:
            state, values = peers.get(name, ('', {}))
            if state != READY and state != RUNNING or values.get('run_id') != self.run_id:
                return False, None
            t_s = int(values.get('T_s_ns', 0) or 0)
            if t_s and t_s != self.period:        # 0: a node without a period (the recorder)
                return False, (f"node '{name}' runs at T_s = {ns_to_s(t_s):g} s, the plant at "
                               f'{ns_to_s(self.period):g} s: give every node the same T_s')
        return True, None

    def not_ready(self, peers: Dict[str, tuple]) -> List[str]:
        """Return the nodes of ``wait_for`` not ready yet."""
        return [n for n in self.wait_for if peers.get(n, ('',))[0] not in (READY, RUNNING)]

    # Peers ---------------------------------------------------------------------------------
    def on_peer(self, name: str, state: str, values: dict, now: float, at_ns: int,
                running: bool, providers: Iterable[str] = ()) -> Tuple[str, str]:
        """
        Take a peer's event: return (decision, text) with decision one of the module's constants.

        ``YIELD``: another time master of the key started first (text: why); ``JOINED`` /
        ``LEFT``: a lossless follower came (while running: counted from ``at_ns``) or went;
        ``STOP``: a node it waits for or reads ended its part (text: the reason); else ``IGNORE``.
        """
        if is_master(values):
            run = values.get('run_id', '')
            if run == self.run_id:
                return IGNORE, ''
            started = _number(values.get('started_at'))
            if started is None and run in self.others:
                started = self.others[run][2]
            self.others[run] = (name, state, started)
            # Discovery is asynchronous: a time master may start before it sees one of the same
            # key that is already running. The later of the two yields (the first run goes on).
            if (self.started_at is not None and state not in END_STATES and started is not None
                    and (started, run) < (self.started_at, self.run_id)):
                return YIELD, yield_text(name, run, self.domain)
            return IGNORE, ''
        if values.get('run_id') != self.run_id:
            return IGNORE, ''               # a node that does not follow this run (yet)
        if state == READY and values.get('lossless') == 'true' and name not in self.followers:
            self.followers[name] = [at_ns if running else 0, now]
            return (JOINED if running else IGNORE), name
        gone = state in (STOPPING, STOPPED) + END_STATES
        if gone and name in self.followers:
            del self.followers[name]
            return LEFT, f"follower '{name}' {state}"
        if gone and (name in self.wait_for or name in providers):
            why = f" ({values['reason']})" if values.get('reason') else ''
            return STOP, f'{name} {state}{why}'
        return IGNORE, ''

    # Lossless followers -------------------------------------------------------------------
    def ack(self, name: str, ns: int, now: float) -> bool:
        """Take follower ``name``'s acknowledgement of step stamp ``ns``; False: not a follower."""
        f = self.followers.get(name)
        if f is None:
            return False
        if ns > f[0]:
            f[0] = ns
        f[1] = now
        return True

    def lagging(self, next_ns: int, now: float) -> Optional[str]:
        """
        Return the first follower more than ``window`` steps behind ``next_ns``, or None.

        A follower silent for ``timeout`` is dropped (``on_dropped``): it is off the critical path
        and must not stop the run (its recording will show the gap).
        """
        limit = next_ns - self.window * self.period
        for name, (ack, seen) in list(self.followers.items()):
            if ack >= limit:
                continue
            if now - seen > self.timeout:
                del self.followers[name]
                if self.on_dropped is not None:
                    self.on_dropped(name, ack)
                continue
            return name
        return None

    def hold(self, inputs, next_ns: int, now: float) -> bool:
        """Park the complete step ``inputs`` (before ``next_ns``) while a follower lags."""
        if self.followers and self.lagging(next_ns, now) is not None:
            self.parked = inputs
            return True
        return False

    def resume(self):
        """Return the parked step's inputs (and forget them), or None."""
        parked, self.parked = self.parked, None
        return parked

    def drained(self, final_ns: int, now: float) -> bool:
        """Tell whether every follower acknowledged enough of the last step ``final_ns``."""
        return not (self.followers
                    and self.lagging(final_ns + (self.window - 1) * self.period, now) is not None)


class LosslessFollower:
    """
    A lossless follower's part of the protocol (the recorder): what it acknowledges, its end.

    ``announced``: run id -> the lock-step topics its nodes said they publish (``publishes`` of
    their ``ready``); ``ack_topics``: the topics whose last step received it acknowledges
    (:data:`im_common.topics.ACKED_TOPICS` and the announced ones it tracks); ``acked``: the last
    acknowledged stamp; ``run_start``/``from_start``: the run's first step and whether the time
    master counted this follower from it; ``end_state``/``end_values``/``end_wall``: the run's
    end as seen (``ENDED`` when the time master left without a final event).
    """

    __slots__ = ('acked_topics', 'tracked', 'announced', 'ack_topics', 'acked', 'run_start',
                 'from_start', 'end_state', 'end_values', 'end_wall', 'event_period',
                 'master_checked', 'master_gone_since')

    #: How long the time master's measurements may have no publisher before it counts as gone [s].
    MASTER_GONE_S = 2.0
    #: The end's grace [s]: once complete, nothing new of this graph for this long after the
    #: later of the end event and the last message (a node's reports of its last step follow its
    #: lock-step message, which completes the recording: counted from the end event alone, a
    #: free_run observer that came late lost them, two graphs on a 2-core machine)
    END_GRACE_S = 0.3
    #: Once complete, the recording ends this long after the end event [s] even if messages of
    #: this graph keep coming (a setpoint published on and on).
    END_LIMIT_S = 3.0
    #: After the end, nothing new for this long [s] ends the recording even if it is behind.
    QUIET_S = 1.0

    def __init__(self, acked_topics: Sequence[str], tracked: Sequence[str]):
        self.acked_topics = tuple(acked_topics)
        self.tracked = tuple(tracked)
        self.announced: Dict[str, set] = {}
        self.ack_topics = [t for t in self.acked_topics if t in self.tracked]
        self.acked = -1
        self.run_start: Optional[int] = None
        self.from_start = False
        self.end_state: Optional[str] = None
        self.end_values: dict = {}
        self.end_wall = 0.0
        self.event_period = 0
        self.master_checked = 0.0
        self.master_gone_since: Optional[float] = None

    def announce(self, run_id: str, publishes: str) -> None:
        """Take a node's ``ready`` list of the lock-step topics it publishes in run ``run_id``."""
        self.announced.setdefault(run_id, set()).update(publishes.split())

    def set_run(self, run_id: str) -> None:
        """Acknowledge the table's topics and those the nodes of ``run_id`` announced."""
        announced = self.announced.get(run_id, ())
        self.ack_topics = [t for t in self.tracked if t in self.acked_topics or t in announced]

    def master_event(self, name: str, state: str, values: dict, period: int, own_name: str,
                     now: float, counted: Optional[bool] = None) -> bool:
        """
        Take an event of the followed run's time master; tell whether the run just started.

        Its ``running`` gives the run's first step and whether it counted this follower from it
        (``own_name`` in its ``followers``, or ``counted`` when given: the in-process graph's
        recording is counted from the start); an end state is the run's end.
        """
        started = False
        if state == RUNNING and self.run_start is None and period:
            self.run_start = int(values.get('step', 0) or 0) * period
            self.from_start = (own_name in values.get('followers', '').split()
                               if counted is None else counted)
            started = True
        if state in END_STATES:
            self.end_state = state
            self.end_values = dict(values, node=name)
            self.end_wall = now
        return started

    def next_ack(self, lasts: Iterable[Optional[int]]) -> Optional[int]:
        """
        Return the stamp to acknowledge now, or None (nothing new).

        That is the last step received on every acknowledged topic (``lasts``, in ``ack_topics``
        order): a topic that has brought nothing yet holds it back, and so the time master.
        """
        ack = None
        for last in lasts:
            if last is None:
                return None
            if ack is None or last < ack:
                ack = last
        if ack is None or ack <= self.acked:
            return None
        self.acked = ack
        return ack

    def master_left(self, now: float, seen: bool, publishers: Callable[[], int],
                    last_ns: Optional[int], period: int) -> bool:
        """
        Tell whether the time master left the graph without a final event (then ``ENDED``).

        Asked at most every 0.5 s once its measurements were ``seen``: no publisher of them for
        :data:`MASTER_GONE_S` ends the run.
        """
        if self.end_state is not None or not seen or now - self.master_checked < 0.5:
            return False
        self.master_checked = now
        if publishers() > 0:
            self.master_gone_since = None
        elif self.master_gone_since is None:
            self.master_gone_since = now
        elif now - self.master_gone_since > self.MASTER_GONE_S:
            self.end_state = ENDED
            self.end_values = {'reason': 'the plant left the graph without a final status',
                               'step': str((last_ns or 0) // max(period, 1))}
            self.end_wall = now
            return True
        return False

    def drained(self, now: float, behind: bool, last_msg: float) -> bool:
        """
        Tell whether the part of this follower is over after the run's end.

        Over: nothing ``behind`` the time master's last step and the end's grace passed since
        the later of the end and ``last_msg`` (at most :data:`END_LIMIT_S` after the end), or
        nothing new came for :data:`QUIET_S`.
        """
        if self.end_state is None:
            return False
        since = now - max(self.end_wall, last_msg)
        settled = since > self.END_GRACE_S or now - self.end_wall > self.END_LIMIT_S
        return (not behind and settled) or since > self.QUIET_S
