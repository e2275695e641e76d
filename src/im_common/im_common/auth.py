"""
Who may command the motor: a per-graph key and a tag on every message that steers the run.

The Fast DDS in the PyPI wheels has no DDS security, so any participant on the ROS domain can
publish on the lock-step topics. The graph protects itself with a secret shared by its own nodes
(``docs/security.md``):

* **The key** (32 random bytes) lives in a file readable by its owner only. ``ros2 launch`` and
  the project's tools make a fresh one per graph (:func:`new_key_file`) and hand its path to every
  node (parameter ``graph_key_file``); nodes started by hand with ``ros2 run`` share the user's
  key (:func:`default_key_file`, created on first use). The in-process graph keeps one in memory.
* **The tag**: a keyed BLAKE2s MAC (16 bytes, 32 hex digits) carried at the end of the
  message's ``header.frame_id`` (``alphabeta#<tag>``). It covers the topic, the run id of the time
  master (so a message of an earlier run cannot be replayed into this one), the stamp, the rest of
  the frame id and every byte after it (the values). A message whose tag does not verify is
  refused by its receiver, counted, and reported with the publishers the graph API shows on that
  topic (:mod:`im_common.lockstep`).
* Run-protocol events (``/im/status``) and the lossless followers' acknowledgements
  (``/im/progress``) carry the same tag over their serialized content.

This is message authentication between processes of one user, not encryption: a process of the
same user can read the key (it could as well attach a debugger), another user cannot. Full ROS
installs can add DDS security (SROS2, ``src/im_bringup/config/sros2/policy.xml``).
"""
from __future__ import annotations

import hashlib
import hmac
import json
import os
import stat
import struct
import tempfile
from typing import Optional

KEY_BYTES = 32
TAG_BYTES = 16
TAG_HEX = 2 * TAG_BYTES
SEPARATOR = '#'
#: Environment variable naming the key file of nodes started by hand (``ros2 run``).
KEY_ENV = 'IM_GRAPH_KEY_FILE'

_U32 = struct.Struct('<I')
_SEPARATOR_BYTE = ord(SEPARATOR)


class GraphKeyError(ValueError):
    """A key file that cannot be used (missing, unreadable, wrong size, readable by others)."""


def default_key_file() -> str:
    """``$IM_GRAPH_KEY_FILE``, else ``$ROS_HOME/im_drive/graph.key`` (``~/.ros/...``)."""
    env = os.environ.get(KEY_ENV)
    if env:
        return env
    home = os.environ.get('ROS_HOME') or os.path.join(os.path.expanduser('~'), '.ros')
    return os.path.join(home, 'im_drive', 'graph.key')


def write_key_file(path: str) -> str:
    """
    Create ``path`` (mode 0600, its directory 0700 if new) holding a fresh random key.

    An existing file is kept (two nodes starting at once end up with the same key).
    """
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, mode=0o700, exist_ok=True)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        return path
    try:
        os.write(fd, os.urandom(KEY_BYTES).hex().encode() + b'\n')
    finally:
        os.close(fd)
    return path


def new_key_file(directory: Optional[str] = None) -> str:
    """Make a fresh key for one graph, in a new private directory (``ros2 launch``, the tools)."""
    d = tempfile.mkdtemp(prefix='im_drive_key_', dir=directory)
    return write_key_file(os.path.join(d, 'graph.key'))


def remove_key_file(path: str) -> None:
    """Remove a key made by :func:`new_key_file` and its directory (missing is fine)."""
    try:
        os.remove(path)
        os.rmdir(os.path.dirname(path))
    except OSError:
        pass


def read_key_file(path: str, create: bool = False) -> bytes:
    """
    Return the key in ``path``.

    Raises a one-line :class:`GraphKeyError` naming the file and what is wrong.
    """
    if create and not os.path.exists(path):
        write_key_file(path)
    try:
        st = os.stat(path)
        with open(path, 'rb') as f:
            text = f.read().strip()
    except OSError as exc:
        raise GraphKeyError(f'graph key file {path}: {exc.strerror}') from None
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise GraphKeyError(f'graph key file {path} is accessible to other users (mode '
                            f'{stat.S_IMODE(st.st_mode):04o}): chmod 600 {path}')
    try:
        key = bytes.fromhex(text.decode('ascii'))
    except (UnicodeDecodeError, ValueError):
        key = b''
    if len(key) < 16:
        raise GraphKeyError(f'graph key file {path} does not hold a key (expected {KEY_BYTES} '
                            f'random bytes as hex digits)')
    return key[:KEY_BYTES]


#: (key, run id, topic) -> the last lock-step message signed or verified for it, shared by every
#: Signer of the process. The tag is a pure function of the key, run id, topic and bytes, so bytes
#: equal to ones already signed or verified verify without hashing again: in one process the
#: message a node signs is checked by up to three others (the in-process graph), and every one of
#: them would compute the same tag. Bounded: cleared when it outgrows :data:`_LAST_MAX`.
_LAST: dict = {}
_LAST_MAX = 1024


class Signer:
    """
    Tags and verifies messages of one graph (one key, one run id at a time).

    Serialized ``Vector3Stamped`` / ``JointState`` (the lock-step topics) are tagged in place of
    the last ``TAG_HEX`` characters of their frame id (:meth:`sign` / :meth:`verify`);
    message objects and other payloads by :meth:`tag_bytes`.
    """

    __slots__ = ('key', 'run_id', '_base', '_ids')

    def __init__(self, key: bytes, run_id: str = ''):
        self.key = bytes(key)
        self.run_id = ''
        self._base = {}
        self._ids = {}
        self.set_run(run_id)

    def set_run(self, run_id: str) -> None:
        self.run_id = run_id or ''
        self._base = {}
        self._ids = {}

    def _hasher(self, topic: str):
        h = self._base.get(topic)
        if h is None:
            h = hashlib.blake2s(key=self.key, digest_size=TAG_BYTES)
            h.update(f'{topic}\0{self.run_id}\0'.encode())
            self._base[topic] = h
        return h.copy()

    def _ident(self, topic: str) -> tuple:
        ident = self._ids[topic] = (self.key, self.run_id, topic)
        return ident

    @staticmethod
    def frame(base: str) -> str:
        """Return the frame id a publisher packs its messages with: ``base#`` + a dummy tag."""
        return base + SEPARATOR + '0' * TAG_HEX

    def _mac(self, topic: str, data: bytes, at: int, end: int) -> bytes:
        """
        Return the tag (hex digits) of a packed message.

        It covers the stamp, the frame id's length and text before the tag, and every byte after
        the frame id (the values).
        """
        h = self._hasher(topic)
        h.update(data[4:at])
        h.update(data[end:])
        return h.hexdigest().encode()

    def sign(self, topic: str, data: bytes) -> bytes:
        """Return ``data`` (packed with :meth:`frame`) with its tag written into the frame id."""
        end = 15 + _U32.unpack_from(data, 12)[0]      # the frame id's NUL
        at = end - TAG_HEX
        signed = data[:at] + self._mac(topic, data, at, end) + data[end:]
        if len(_LAST) >= _LAST_MAX:
            _LAST.clear()
        _LAST[self._ids.get(topic) or self._ident(topic)] = signed
        return signed

    def verify(self, topic: str, data: bytes) -> bool:
        """Return True if ``data`` carries this graph's tag for ``topic`` in the current run."""
        ident = self._ids.get(topic) or self._ident(topic)
        if _LAST.get(ident) == data:
            return True                 # the very bytes signed or verified last: same tag
        try:
            n = _U32.unpack_from(data, 12)[0]
        except struct.error:
            return False
        end = 15 + n
        at = end - TAG_HEX
        if n < TAG_HEX + 2 or end > len(data) or data[at - 1] != _SEPARATOR_BYTE:
            return False
        if not hmac.compare_digest(self._mac(topic, data, at, end), bytes(data[at:end])):
            return False
        if len(_LAST) >= _LAST_MAX:
            _LAST.clear()
        _LAST[ident] = bytes(data)
        return True

    def tag_bytes(self, topic: str, payload: bytes) -> str:
        """Return the tag of an arbitrary payload (a serialized message with an empty tag slot)."""
        h = self._hasher(topic)
        h.update(payload)
        return h.hexdigest()

    def check_bytes(self, topic: str, payload: bytes, tag: str) -> bool:
        return hmac.compare_digest(self.tag_bytes(topic, payload).encode(), tag.encode())


def status_payload(msg) -> bytes:
    """
    Return what a status event's tag covers (a ``diagnostic_msgs/DiagnosticArray``).

    That is its stamp and every field of every status, encoded canonically (rclpy's serialization
    leaves padding bytes undefined, so it cannot be signed).
    """
    st = msg.header.stamp
    return json.dumps([st.sec, st.nanosec, [
        [int.from_bytes(s.level, 'little') if isinstance(s.level, bytes) else int(s.level),
         s.name, s.message, s.hardware_id, [[kv.key, kv.value] for kv in s.values]]
        for s in msg.status]], separators=(',', ':')).encode()


def progress_payload(node: str, stamp_ns: int) -> bytes:
    """Return what a lossless follower's acknowledgement tag covers: its name and acked stamp."""
    return f'{node}\0{int(stamp_ns)}'.encode()


def split_frame(frame_id: str):
    """Return (base, tag) of a tagged frame id; (frame_id, '') when it carries no tag."""
    if len(frame_id) > TAG_HEX and frame_id[-TAG_HEX - 1] == SEPARATOR:
        return frame_id[:-TAG_HEX - 1], frame_id[-TAG_HEX:]
    return frame_id, ''
