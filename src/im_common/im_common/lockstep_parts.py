"""
The ROS-free bookkeeping of a lock-step node: who publishes, readiness, the input watchdog.

Unit-tested without rclpy (``tests/test_lockstep_parts.py``). :class:`im_common.lockstep.
LockstepNode` asks the ROS graph (publishers of a topic, their count) and hands the answers here:
- :class:`PublisherWatch`: the publishers its inputs may have, the foreign ones already named, how
  often to look, and the texts that name them (a refused message, another graph on the domain);
- :class:`Readiness`: when a node waiting for its inputs' publishers and its time master is ready,
  or has waited too long, and what it says meanwhile;
- :class:`InputWatchdog`: how long an exact gate may wait for its step, and a node that finished
  its last step for the time master's end.
"""
from __future__ import annotations

import difflib
import struct
import time
from typing import Callable, Dict, Iterable, List, Optional

from .conversions import NS_PER_S
from .lockstep_protocol import READY, RUNNING, WaitClock, watchdog_limit
from .signing import allowed_publishers, foreign_publishers
from .step_gate import finite

#: Period of a node's watchdog tick [s] (start-up, input timeouts: :class:`WaitClock`).
WATCHDOG_TICK_S = 0.1

_STAMP = struct.Struct('<iI')


def stamp_text(ns: int) -> str:
    return f'{ns / NS_PER_S:.9f} s'


def logs_refusal(n: int) -> bool:
    """Tell whether the ``n``-th refused input is logged: the first 20, then every 1000th."""
    return n <= 20 or n % 1000 == 0


def header_stamp(data: bytes) -> Optional[int]:
    """Return the header stamp [ns] of a serialized stamped message, None if it holds none."""
    try:
        sec, nsec = _STAMP.unpack_from(data, 4)
    except struct.error:
        return None
    return sec * NS_PER_S + nsec


def input_handler(node, topic: str, extract: Callable, take: Optional[Callable] = None,
                  hold=None) -> Callable[[bytes], None]:
    """
    Return the handler of a lock-step input's serialized messages: the one path of every input.

    Each message is verified (``node.signer``: this graph's tag for the run followed; else
    ``node.unsigned_input``), decoded by ``extract(data)`` = (stamp_ns, value), checked finite
    (else the last good value, at first ``hold``, is held; with none the message is dropped) —
    refusals counted (``node.rejected``) and logged (``node.refuse``), never fatal; then
    ``take(ns, value)``, if given, may keep it from the gate (False); complete steps of
    ``node.gate`` go to ``node.ready`` (a follow gate's incomplete ones to
    ``node.on_incomplete``). The hot path: locals only, no allocation of its own.
    """
    gate, ready, verify, refuse = node.gate, node.ready, node.signer.verify, node.refuse
    held = hold

    def on_data(data):
        nonlocal held
        if not verify(topic, data):
            node.unsigned_input(topic, data, on_data)
            return
        try:
            ns, value = extract(data)
        except (ValueError, KeyError, IndexError) as exc:
            node.rejected += 1
            refuse(topic, None, f'cannot decode: {exc}')
            return
        if not finite(value):
            node.rejected += 1
            refuse(topic, ns, f'non-finite value {value!r}; ' + (
                'holding the previous one' if held is not None else 'nothing to hold yet'))
            if held is None:
                return
            value = held
        else:
            held = value
        if take is not None and not take(ns, value):
            return
        inputs = gate.put(topic, ns, value)
        if inputs is not None:          # the step is complete
            ready(inputs)
        elif gate.follow:
            node.on_incomplete(topic, ns)
    return on_data


def foreign_status_text(topic: str, state: str, sender: str, pubs: List[str]) -> str:
    """Say that a run-protocol event not signed by this graph is ignored (named, once)."""
    return (f"ignoring {topic} event '{state}' from '{sender}': not signed by this graph "
            f'(another graph with its own key, or a foreign node'
            + (f"; publishers not of this graph: {', '.join(pubs)}" if pubs else '') + ')')


def stall_text(missing: List[str], gone: List[str], expected: int, step: int, limit: float,
               crosstalk: str) -> str:
    """Say which inputs an exact gate waited for past its limit (the node then fails)."""
    hint = f' ({", ".join(gone)} no longer has a publisher)' if gone else ''
    return (f"no {', '.join(missing)} stamped {stamp_text(expected)} (step {step}) within "
            f'{limit:.1f} s of wall time this process ran{hint}{crosstalk}; stopping')


class PublisherWatch:
    """
    Who may publish on a node's inputs, who else does, and when to ask the graph again.

    ``allowed``: topic -> allowed publishers ('/ns/name', :func:`allowed_publishers`);
    ``foreign``: topic -> the foreign publishers seen (each reported once).
    """

    __slots__ = ('allowed', 'foreign', 'checked_at', 'asked_at', 'status_said')

    #: How often the watchdog looks at the inputs' publishers [s].
    CHECK_S = 1.0
    #: How often a refused message may make the node ask the graph [s] (cheap under a flood).
    ASK_S = 0.1

    def __init__(self, namespace: str, text: str):
        self.allowed: Dict[str, set] = allowed_publishers(namespace, text)
        self.foreign: Dict[str, set] = {}
        self.checked_at = 0.0
        self.asked_at = 0.0
        self.status_said: set = set()       # senders of foreign events named (at most 100)

    def first_status_from(self, sender: str) -> bool:
        """Tell whether a foreign event of ``sender`` is the first one seen (then note it)."""
        if sender in self.status_said or len(self.status_said) > 100:
            return False
        self.status_said.add(sender)
        return True

    def due(self, now: float) -> bool:
        """Tell whether to look at the publishers now (about every second); if so, note it."""
        if now - self.checked_at < self.CHECK_S:
            return False
        self.checked_at = now
        return True

    def after_refusal(self, now: float) -> bool:
        """Tell whether a refused message makes the node look now (then it looks at once)."""
        if now - self.asked_at < self.ASK_S:
            return False
        self.asked_at = now
        self.checked_at = 0.0
        return True

    def outsiders(self, topic: str, infos: Iterable) -> List[str]:
        """Return the publishers in ``infos`` (graph API) not allowed on ``topic``."""
        return foreign_publishers(self.allowed.get(topic), infos)

    def new_foreign(self, topic: str, nodes: Iterable[str], ros_time: bool) -> List[tuple]:
        """
        Return (node, report) of each foreign publisher of ``topic`` not reported yet.

        ``ros_time``: the topic only sets ROS time (``/clock``), which no computation uses.
        """
        seen = self.foreign.setdefault(topic, set())
        out = []
        for node in nodes:
            if node in seen:
                continue
            seen.add(node)
            effect = ('ignored: the drive computes on step stamps, never on ROS time' if ros_time
                      else 'its messages are refused')
            allowed = ', '.join(sorted(self.allowed.get(topic, ())))
            out.append((node, f'foreign publisher {node} on {topic} (allowed: {allowed}): '
                              f'{effect}'))
        return out

    def unsigned_text(self, topic: str, run_id: str) -> str:
        """Say why a message of ``topic`` without this graph's tag for ``run_id`` is refused."""
        pubs = sorted(self.foreign.get(topic, ()))
        who = (f"foreign publisher{'s' if len(pubs) > 1 else ''} on it: {', '.join(pubs)}"
               if pubs else 'its publisher uses an allowed name: another graph with its own '
               'key, or a node of an earlier run')
        return f"not signed by this graph for run {run_id or '(none yet)'} ({who})"


def crosstalk_text(busy: List[str], domain) -> str:
    """Name the lock-step topics with more than one publisher: another graph on the domain."""
    if not busy:
        return ''
    return (f'; {", ".join(busy)} ha{"ve" if len(busy) > 1 else "s"} more than one publisher:'
            f' another graph is on this ROS domain (ROS_DOMAIN_ID={domain}) — give each graph '
            f'its own')


def unknown_parameter(node: str, given: Iterable[str], declared: Iterable[str]) -> Optional[str]:
    """
    Return the one line refusing parameters given for ``node`` that it does not declare, or None.

    It names the nearest valid one: a misspelt gain must not silently fall back to its default.
    """
    declared = sorted(declared)
    unknown = sorted(n for n in given if n not in declared and not n.startswith('qos_overrides.'))
    if not unknown:
        return None
    name = unknown[0]
    near = difflib.get_close_matches(name, declared, n=1, cutoff=0.5)
    hint = f"; did you mean '{near[0]}'?" if near else ''
    also = f' (also unknown: {", ".join(unknown[1:])})' if unknown[1:] else ''
    return f"unknown parameter '{name}' for node '{node}'{hint}" + also


def waiting_text(missing: List[str], time_master: bool, run_id: str) -> str:
    """Say what a node waits for before it is ready."""
    if missing:
        return 'no publisher yet of ' + ', '.join(missing)
    if not time_master and not run_id:
        return "no run-protocol event of a time master (plant) signed with this graph's key"
    return 'waiting'


class Readiness:
    """
    A node's start-up: from ``waiting`` to ``ready`` once its inputs have publishers.

    (And, unless it is the time master, once it follows a run.) ``said``: the missing inputs it
    last announced; ``since``: when it started waiting (monotonic).
    """

    __slots__ = ('startup_timeout', 'since', 'said', 'logged')

    #: How often a waiting node logs what it waits for [s].
    LOG_S = 2.0

    def __init__(self, startup_timeout: float, now: float):
        self.startup_timeout = float(startup_timeout)
        self.since = now
        self.said: Optional[List[str]] = None
        self.logged = 0.0

    def announce(self, missing: List[str]) -> bool:
        """Tell whether ``missing`` differs from what the node last said it waits for."""
        if missing == self.said:
            return False
        self.said = missing
        return True

    def waited(self, now: float) -> float:
        return now - self.since

    def over(self, now: float) -> bool:
        """Tell whether the node waited longer than its startup timeout."""
        return now - self.since > self.startup_timeout

    def log_due(self, now: float) -> bool:
        """Tell whether to log the wait now (every :data:`LOG_S`)."""
        waited = now - self.since
        if waited - self.logged < self.LOG_S:
            return False
        self.logged = waited
        return True


def providers(inputs: Iterable[str], nodes_of: Callable[[str], Iterable[str]]) -> Dict[str, str]:
    """Return publisher node name -> one input topic it provides (the first, by name)."""
    out: Dict[str, str] = {}
    for t in inputs:
        for n in sorted(set(nodes_of(t))):
            out.setdefault(n, t)
    return out


class InputWatchdog:
    """
    How long a node may wait: for its exact gate's next step, and after its last step.

    ``timeout`` is ``input_timeout``, ``startup_timeout`` the bound before step 0; ``since`` when
    the node finished its last step (or became ready).
    """

    __slots__ = ('timeout', 'startup_timeout', 'since', 'clock')

    def __init__(self, timeout: float = 5.0, startup_timeout: float = 30.0):
        self.timeout = float(timeout)
        self.startup_timeout = float(startup_timeout)
        self.since = time.monotonic()
        self.clock = WaitClock(WATCHDOG_TICK_S)

    def finish_wait(self) -> float:
        """Return how long a node that finished waits for the time master's end [s]."""
        return max(self.timeout, 1.0)

    def finish_over(self, now: float) -> bool:
        return now - self.since > self.finish_wait()

    def finish_text(self, last_step: int) -> str:
        """Say that the time master did not confirm the end after this node's last step."""
        return (f'finished step {last_step - 1}; the plant did not confirm the end within '
                f'{self.finish_wait():.1f} s')

    def stalled(self, state: str, gate_since: float, now: float,
                time_master: bool) -> Optional[float]:
        """Return the limit [s] an exact gate's expected step passed in ``state``, or None."""
        if state != RUNNING and state != READY:
            return None
        limit = watchdog_limit(state, self.timeout, self.startup_timeout, time_master)
        return limit if self.clock.waited(gate_since, now) > limit else None
