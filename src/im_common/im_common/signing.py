"""
Message signing of one lock-step node.

Its tags, its checks, and the messages kept for a run it has not adopted yet.

ROS-free (unit-tested without rclpy in ``tests/test_lockstep_parts.py``); the tags themselves are
:mod:`im_common.auth`'s. :class:`im_common.lockstep.LockstepNode` signs every lock-step message it
publishes with :meth:`NodeSigning.sign`, verifies every input with :meth:`NodeSigning.verify`, and
signs and checks its run-protocol events with :meth:`NodeSigning.status_tag` /
:meth:`NodeSigning.status_verifies`.

Before the run a node follows is running, an input that does not verify for it may still be of
the run it is about to follow (the plant's ``running`` and the first steps race each other across
topics): such messages are kept, bounded (:meth:`NodeSigning.keep_early`), and handed back when
the node adopts or locks on a run (:meth:`NodeSigning.take_early`).

Who may publish on a node's inputs besides (:func:`allowed_publishers`): the topic table's
publisher in the node's namespace and the ``allowed_publishers`` parameter's items; any other
publisher the graph shows is named (:func:`foreign_publishers`) — its messages are refused anyway,
since they do not carry this graph's tag.
"""
from __future__ import annotations

from typing import Callable, Dict, Iterable, List, Optional, Sequence, Tuple

from . import auth
from .topics import TOPICS

#: The node name the graph API gives a participant whose node is not discovered yet.
UNKNOWN_NODE = '_NODE_NAME_UNKNOWN_'


class NodeSigning:
    """
    The signers of one node (one graph key).

    It holds ``signer`` for the lock-step messages of the run it follows (:meth:`set_run`),
    ``status_signer`` for ``/im/status`` events and ``/im/progress`` acknowledgements, and one per
    other run a message was checked against.

    ``early_max`` bounds the messages kept before the run is known; when full, ``keep_newest``
    False refuses the new message (a follower needs the first steps of its run, which come
    first), True refuses the oldest kept one instead (the recorder: it records contiguously from
    where it joined, so what it keeps must reach up to now).
    """

    __slots__ = ('key', 'signer', 'status_signer', 'status_topic', 'early', 'early_max',
                 'keep_newest', '_candidates')

    def __init__(self, key: bytes, status_topic: str, early_max: int, keep_newest: bool = False):
        self.key = bytes(key)
        self.signer = auth.Signer(self.key)
        self.status_signer = auth.Signer(self.key)
        self.status_topic = status_topic
        self.early: List[tuple] = []          # (topic, data, handler), oldest first
        self.early_max = early_max
        self.keep_newest = keep_newest
        self._candidates: Dict[str, auth.Signer] = {}

    # Lock-step messages ---------------------------------------------------------------------
    def set_run(self, run_id: str) -> None:
        """Sign and verify for the time master's run ``run_id`` from now on."""
        self.signer.set_run(run_id)

    def sign(self, topic: str, data: bytes) -> bytes:
        """Tag a lock-step message of this node for the run it follows."""
        return self.signer.sign(topic, data)

    def verify(self, topic: str, data: bytes) -> bool:
        """Return True if ``data`` carries this graph's tag for ``topic`` in the run followed."""
        return self.signer.verify(topic, data)

    def signer_for(self, run_id: str) -> auth.Signer:
        """Return a signer of this key for another run (kept: checked again for every message)."""
        signer = self._candidates.get(run_id)
        if signer is None:
            signer = self._candidates[run_id] = auth.Signer(self.key, run_id)
        return signer

    # Run-protocol events --------------------------------------------------------------------
    def status_tag(self, msg) -> str:
        """Return the tag of a status event, over its content (:func:`auth.status_payload`)."""
        return self.status_signer.tag_bytes(self.status_topic, auth.status_payload(msg))

    def status_verifies(self, msg) -> bool:
        """Tell whether the event carries this graph's tag (in ``header.frame_id``)."""
        return self.status_signer.check_bytes(self.status_topic, auth.status_payload(msg),
                                              msg.header.frame_id)

    # Messages of a run not adopted yet ---------------------------------------------------------
    def keep_early(self, topic: str, data: bytes, handler: Callable,
                   runs: Optional[Sequence[str]]) -> Optional[Tuple[str, bytes]]:
        """
        Keep ``data``, not verifying for the run followed now, if it may be of a run to come.

        That is a run this node could still follow: before any time master was seen (``runs`` None)
        anything, afterwards only what verifies for one of ``runs`` — a flood of foreign messages
        cannot push the graph's own out. Returns the message refused, (topic, data), or None.
        """
        if not self.keep_newest and len(self.early) >= self.early_max:
            return topic, data
        if runs is not None and not any(self.signer_for(r).verify(topic, data) for r in runs):
            return topic, data
        self.early.append((topic, data, handler))
        if len(self.early) > self.early_max:
            old_topic, old_data, _ = self.early.pop(0)
            return old_topic, old_data
        return None

    def unsigned(self, topic: str, data: bytes, handler: Callable, protocol,
                 time_master: bool) -> Optional[Tuple[str, bytes]]:
        """
        Take ``data``, which does not verify for the run followed now: return what is refused.

        Before that run is running (``protocol.locked``) it may belong to the run this node is
        about to follow: kept (:meth:`keep_early`), handed to ``handler`` again when a run is
        adopted or locked; a time master follows no other run. Returns (topic, data) refused, or
        None.
        """
        if protocol.locked or time_master:
            return topic, data
        return self.keep_early(topic, data, handler,
                               protocol.other_live_runs() if protocol.masters else None)

    def take_early(self) -> List[tuple]:
        """Return and clear the messages kept so far, (topic, data, handler), oldest first."""
        early, self.early = self.early, []
        return early

    def drain(self) -> None:
        """Hand every message kept so far to its handler again, oldest first (a run changed)."""
        for _topic, data, handler in self.take_early():
            handler(data)


def allowed_publishers(namespace: str, text: str) -> Dict[str, set]:
    """
    Return topic -> allowed publisher nodes ('/ns/name').

    They are the topic table's publisher in ``namespace``, plus the items of ``text`` (the
    ``allowed_publishers`` parameter: space-separated ``/topic=node``, a node without a leading '/'
    in ``namespace``).
    """
    ns = namespace.rstrip('/')
    allowed = {t.name: {f'{ns}/{t.publisher}'} for t in TOPICS if ' ' not in t.publisher}
    for item in text.split():
        topic, sep, node = item.partition('=')
        if not sep or not topic.startswith('/') or not node:
            raise ValueError(f"invalid parameter 'allowed_publishers' item {item!r}: "
                             'expected /topic=node')
        allowed.setdefault(topic, set()).add(node if node.startswith('/') else f'{ns}/{node}')
    return allowed


def foreign_publishers(allowed: Optional[set], infos: Iterable) -> List[str]:
    """
    Return the publishers in ``infos`` not in ``allowed``, as '/ns/name', each once.

    ``infos`` are the graph API's, with ``node_namespace`` and ``node_name``; ``allowed`` None
    allows any. A participant whose node is not discovered yet is left for the next look.
    """
    out: List[str] = []
    for i in infos:
        if i.node_name == UNKNOWN_NODE:
            continue
        full = f'{i.node_namespace.rstrip("/")}/{i.node_name}'
        if allowed is not None and full not in allowed and full not in out:
            out.append(full)
    return out
