"""
Salvage a recording cut short by a hard kill or damaged on disk.

``ros2 run im_recording recover bags/broken.mcap [-o fixed.mcap] [--force]``

The file is read once, front to back, one record at a time (opcode, 64-bit length, body), and
every record is validated before anything in it is used: a known data-section opcode, a length
inside the file, fields that parse to exactly that length, and for a Chunk a compression the
project's writer uses, its declared sizes and its CRC over the uncompressed records (then the
inner records must parse to exactly the chunk's size). Schemas, Channels, Metadata and every
message of every intact chunk are streamed into :class:`~im_recording.bag.BagWriter` as they are
read, so memory holds one chunk plus the per-channel tables, however long the file.

A record that fails is damage. Reading resumes at the first later offset where a validated
record starts: a Chunk whose CRC checks, a Data End that is followed by a valid summary and
footer (or by the end of the file, or whose data-section CRC matches), or a run of records that
parse exactly and ends in one of those (the damaged chunk's Message Index records, a Channel
declared between chunks). Candidates are found by one regular-expression pass over the bytes after
the damage, so the search is linear; a byte pattern alone is never taken for a record.

What was lost is reported exactly: the time range and the message count of the damaged chunks,
taken from the file's chunk index when its summary is intact (CRC checked), else from the damaged
chunk's own header and the Message Index records that follow it, else bounded by the neighbouring
intact chunks. A file its writer did not close (no Data End: killed, or its disk full) says
nothing of what came after its last record: the tail from the last saved stamp to the end of the
run — the time master's final event when it was saved (nothing is lost once the last saved stamp
reaches it), else the ``run`` record's duration, else unknown — is reported as lost too, and the
output's ``run`` record gets the duration of what was saved. Exit code 0: every record of the
file was read and kept, and nothing is missing after it; 1: the output was written but damaged
bytes were skipped, messages were read but not copied (a channel in another encoding, its schema
lost, its QoS metadata that does not parse) or the run's tail is missing (each loss is printed on
stderr and stored in the output's ``recovered_from`` metadata); 2: nothing written (one line
says why).

The output (default ``<name>.recovered.mcap``; never an input, an existing file only with
``--force``) is written to a temporary file next to it and renamed into place when complete; if
writing fails (disk full) the temporary file is removed. The input is only ever opened for
reading: ``recover run.mcap.part -o run.mcap`` turns an interrupted recording into the file it
was meant to become. A writer that was killed leaves its data in ``<name>.mcap.part``;
``recover <name>.mcap`` reads that.
"""
from __future__ import annotations

import argparse
import bisect
from dataclasses import dataclass, field
import os
from pathlib import Path
import re
import struct
import sys
import tempfile
from typing import Dict, List, Optional, Tuple
import zlib

from im_common import cdr
from im_common.cli import error as cli_error, parse_args
from im_common.conversions import ns_to_s, s_to_ns
from im_common.stopping import exit_code_for, StopSignals
import yaml

from .bag import (BagError, BagWriter, check_output, log_time_offset, LOG_TIME_RECORD,
                  partial_path)
from .mcap_records import (CHUNK_HEAD, chunk_records, COMPRESSIONS, Damage, exact, MAGIC,
                           MAX_CHUNK, MSG_FIXED, need, OP_ATTACHMENT, OP_ATTACHMENT_INDEX,
                           OP_CHANNEL, OP_CHUNK, OP_CHUNK_INDEX, OP_DATA_END, OP_FOOTER,
                           OP_HEADER, OP_MESSAGE, OP_MESSAGE_INDEX, OP_METADATA,
                           OP_METADATA_INDEX, OP_SCHEMA, OP_STATISTICS, OP_SUMMARY_OFFSET,
                           parse_attachment, parse_channel, parse_message_index, parse_metadata,
                           parse_schema, read_string, REC, U32, U64)
from .recorded_run import load_run

#: records that parse but prove nothing (Message Index, Channel, ...) accepted in a row while
#: resynchronising before a CRC-checked record or the end of the file must vouch for them
MAX_CHAIN = 4096
_WINDOW = 1 << 20
_DATA_OPS = frozenset((OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_MESSAGE_INDEX,
                       OP_ATTACHMENT, OP_METADATA, OP_DATA_END))
_SUMMARY_OPS = frozenset((OP_SCHEMA, OP_CHANNEL, OP_CHUNK_INDEX, OP_ATTACHMENT_INDEX,
                          OP_STATISTICS, OP_METADATA_INDEX, OP_SUMMARY_OFFSET))
# where a resynchronisation may start: a record of these kinds with a length below 2**40
# (a Message may not: it carries no check and a damaged uncompressed chunk is full of them)
_CANDIDATE = re.compile(rb'(?=[\x03\x04\x06\x07\x09\x0c\x0f][\x00-\xff]{5}\x00\x00\x00)', re.S)


# ------------------------------------------------------------------------------------------
# What was lost
# ------------------------------------------------------------------------------------------
@dataclass
class Lost:
    """Bytes ``start``..``end`` skipped as damaged, and what is known of the messages in them."""

    start: int
    end: int
    why: str
    header: Optional[Tuple[int, int, int]] = None      # damaged chunk's (t0, t1, record end)
    index: Dict[int, Tuple[int, int, int]] = field(default_factory=dict)  # MI offset -> n, t0, t1
    before: Optional[int] = None          # last stamp of the intact chunk before the damage
    after: Optional[int] = None           # first stamp of the intact chunk after it
    # from the file's own chunk index (summary CRC checked), when it has one
    chunks: int = 0
    chunk_t: Optional[Tuple[int, int]] = None
    chunk_mi: set = field(default_factory=set)
    indexed: bool = False                 # that chunk index was read (so chunks == 0 is known)
    # the conclusion
    t0: Optional[int] = None
    t1: Optional[int] = None
    messages: Optional[int] = None
    source: str = ''

    def settle(self) -> None:
        full = [v for v in self.index.values() if v[0]]
        idx_n = sum(v[0] for v in full)
        idx_t = (min(v[1] for v in full), max(v[2] for v in full)) if full else None
        if self.chunk_t is not None:
            self.t0, self.t1 = self.chunk_t
            self.source = f'{self.chunks} chunk{"s" if self.chunks > 1 else ""} per the file\'s ' \
                          'chunk index'
            if self.chunk_mi and self.chunk_mi <= set(self.index):
                self.messages = sum(self.index[o][0] for o in self.chunk_mi)
        elif self.indexed:
            self.messages = 0
            self.source = "no chunk in them per the file's chunk index"
        elif self.header is not None and self.index and min(self.index) == self.header[2]:
            # the damaged chunk's own header, and its message index right after it
            self.t0, self.t1 = self.header[0], self.header[1]
            if idx_t is not None:
                self.t0, self.t1 = min(self.t0, idx_t[0]), max(self.t1, idx_t[1])
            self.messages = idx_n
            self.source = '1 chunk per its header and message index'
        elif self.header is not None:
            self.t0, self.t1 = self.header[0], self.header[1]
            self.source = '1 chunk per its header'
        elif idx_t is not None:
            self.t0, self.t1 = idx_t
            self.messages = idx_n
            self.source = ('per the message index after the damage; the damaged bytes may hold '
                           'more')

    def as_dict(self) -> dict:
        return {'bytes': [self.start, self.end], 'why': self.why, 't0_ns': self.t0,
                't1_ns': self.t1, 'messages': self.messages, 'source': self.source,
                'between_ns': [self.before, self.after]}

    def text(self) -> str:
        where = f'skipped bytes {self.start}-{self.end}: {self.why}'
        n = (f'{self.messages} message{"s" if self.messages != 1 else ""}'
             if self.messages is not None else 'an unknown number of messages')
        if self.t0 is not None:
            return f'lost t = {ns_to_s(self.t0):.9f} .. {ns_to_s(self.t1):.9f} s, {n} ' \
                   f'({self.source}; {where})'
        if self.messages == 0:
            return f'no messages lost ({self.source}; {where})'

        def s(t):
            return f'{ns_to_s(t):.9f} s'
        span = ('between ' + s(self.before) + ' and ' + s(self.after)
                if self.before is not None and self.after is not None
                else f'after {s(self.before)}' if self.before is not None
                else f'before {s(self.after)}' if self.after is not None else 'at unknown times')
        return f'lost {n} {span} (the damaged bytes say nothing readable; {where})'


# ------------------------------------------------------------------------------------------
# Reading
# ------------------------------------------------------------------------------------------
class _Source:

    def __init__(self, path: Path):
        self.path = path
        try:
            self.f = open(path, 'rb')
            self.size = os.fstat(self.f.fileno()).st_size
        except OSError as exc:
            raise BagError(path, f'cannot read: {exc.strerror or exc}') from None

    def read(self, off: int, n: int) -> bytes:
        try:
            self.f.seek(off)
            return self.f.read(n)
        except OSError as exc:
            raise BagError(self.path,
                           f'cannot read at byte {off}: {exc.strerror or exc}') from None

    def close(self) -> None:
        self.f.close()


class _Scan:
    """One pass over the file; ``sink`` receives what is intact, in file order."""

    def __init__(self, src: _Source, sink):
        self.src, self.sink, self.size = src, sink, src.size
        self.lost: List[Lost] = []
        self.open_loss: Optional[Lost] = None
        self.t_last: Optional[int] = None       # last stamp of the last intact chunk
        self.complete = False
        self.ending = ''
        self.crc: Optional[int] = zlib.crc32(MAGIC)   # data-section CRC while nothing skipped
        self.crc_mismatch = False
        self.attachments = 0
        self.torn_index = False
        self.last_op = 0
        self.last_chunk: list = []              # the last intact chunk's messages
        self._chunk_ok: Dict[int, bool] = {}
        self._dead: set = set()                 # offsets where no validated run starts
        self.summary = self._footer()           # (summary start, its end) if CRC-checked

    # -- footer / summary ------------------------------------------------------------------
    def _footer(self) -> Optional[Tuple[int, int, int]]:
        """
        Locate a valid footer and its summary.

        (summary start, summary end, footer start) when the file ends in a valid footer and its
        summary (CRC checked where it has one) parses; None otherwise.
        """
        size = self.size
        fstart = size - 8 - 29
        if fstart < 8 or self.src.read(size - 8, 8) != MAGIC:
            return None
        foot = self.src.read(fstart, 29)
        op, length = REC.unpack_from(foot, 0)
        if op != OP_FOOTER or length != 20:
            return None
        start, ostart, crc = struct.unpack_from('<QQI', foot, 9)
        if start == 0:
            return (fstart, fstart, fstart)
        if not 8 < start <= fstart or not (ostart == 0 or start <= ostart <= fstart):
            return None
        if crc:
            c, p = 0, start
            while p < size - 8 - 4:
                block = self.src.read(p, min(_WINDOW, size - 8 - 4 - p))
                if not block:
                    return None
                c = zlib.crc32(block, c)
                p += len(block)
            if c != crc:
                return None
        p = start
        while p < fstart:
            op, length = REC.unpack_from(self.src.read(p, 9), 0) if p + 9 <= fstart else (0, 0)
            if op not in _SUMMARY_OPS or p + 9 + length > fstart:
                return None
            p += 9 + length
        return (start, ostart or fstart, fstart)

    def _end_ok(self, pos: int, crc: Optional[int]) -> bool:
        """
        Return a Data End record at ``pos`` validates.

        The end of the file or the summary follows it, or its data-section CRC matches
        ``crc`` (the CRC of everything before it).
        """
        end = pos + 13
        if end == self.size:
            return True
        if self.summary is not None and self.summary[0] == end:
            return True
        if crc is not None:
            (stored,) = U32.unpack_from(self.src.read(pos + 9, 4), 0)
            return stored != 0 and stored == crc
        return False

    # -- validation at an offset -------------------------------------------------------------
    def _head(self, pos: int) -> Optional[Tuple[int, int]]:
        if pos + 9 > self.size:
            return None
        return REC.unpack_from(self.src.read(pos, 9), 0)

    def _chunk_valid(self, pos: int, length: int) -> bool:
        ok = self._chunk_ok.get(pos)
        if ok is None:
            try:
                chunk_records(self.src.read(pos + 9, length))
                ok = True
            except Damage:
                ok = False
            if len(self._chunk_ok) > 4096:
                self._chunk_ok.clear()
            self._chunk_ok[pos] = ok
        return ok

    def _starts_here(self, pos: int) -> bool:
        """
        Return the records that parse exactly from ``pos`` on.

        The run ends in one that carries a check (a Chunk or Attachment whose CRC matches, a Data
        End that validates) or at the end of the file. A run found to fail is remembered, so no
        offset is walked twice.
        """
        seen: List[int] = []
        ok = self._walk(pos, seen)
        if ok is None:              # too long a run to judge: nothing learnt about its offsets
            return False
        if not ok:
            if len(self._dead) > 1 << 17:
                self._dead.clear()
            self._dead.update(seen)
        return ok

    def _walk(self, pos: int, seen: List[int]) -> Optional[bool]:
        n, j = 0, pos
        while n < MAX_CHAIN:
            if j == self.size:
                return n > 0
            if j in self._dead:
                return False
            seen.append(j)
            h = self._head(j)
            if h is None:
                return False
            op, length = h
            end = j + 9 + length
            if op not in _DATA_OPS or op == OP_MESSAGE or end > self.size:
                return False
            if op == OP_CHUNK:
                return self._chunk_valid(j, length)
            if op == OP_DATA_END:
                return length == 4 and self._end_ok(j, None)
            if length > (1 << 26):
                return False
            try:
                body = self.src.read(j + 9, length)
                if op == OP_ATTACHMENT:
                    parse_attachment(body)
                    return True
                {OP_SCHEMA: parse_schema, OP_CHANNEL: parse_channel,
                 OP_MESSAGE_INDEX: parse_message_index, OP_METADATA: parse_metadata}[op](body)
            except Damage:
                return False
            n, j = n + 1, end
        return None

    def _resync(self, start: int) -> Optional[int]:
        """
        Return the first offset >= ``start`` where :meth:`_starts_here`; None if there is none.

        One regular-expression pass over the bytes (read in windows growing from 64 KiB to
        1 MiB); only offsets shaped like a record header are tried.
        """
        pos, win_size = start, 1 << 16
        while pos < self.size:
            win = self.src.read(pos, win_size + 8)
            for m in _CANDIDATE.finditer(win):
                i = m.start()
                if i >= win_size:
                    break
                if self._starts_here(pos + i):
                    return pos + i
            pos += win_size
            win_size = min(2 * win_size, _WINDOW)
        return None

    def _plausible_chunk(self, pos: int) -> Optional[Tuple[int, int, int]]:
        h = self._head(pos)
        if h is None or h[0] != OP_CHUNK:
            return None
        end = pos + 9 + h[1]
        head = self.src.read(pos + 9, min(h[1], 64))
        try:
            if len(head) < CHUNK_HEAD.size + 4:
                raise Damage('short')
            t0, t1, usize, _ = CHUNK_HEAD.unpack_from(head, 0)
            comp, p = read_string(head, CHUNK_HEAD.size)
            if comp not in COMPRESSIONS or t0 > t1 or usize > MAX_CHUNK:
                raise Damage('bad')
            if p + 8 <= len(head) and p + 8 + U64.unpack_from(head, p)[0] != h[1]:
                raise Damage('bad')
        except Damage:
            return None
        return t0, t1, end

    # -- the pass ----------------------------------------------------------------------------
    def _damage(self, pos: int, why: str, next_guess: Optional[int]) -> Optional[int]:
        loss = Lost(pos, self.size, why, header=self._plausible_chunk(pos), before=self.t_last)
        nxt = None
        if next_guess is not None and pos < next_guess <= self.size and \
                self._starts_here(next_guess):
            nxt = next_guess
        if nxt is None:
            nxt = self._resync(pos + 1)
        if nxt is not None:
            loss.end = nxt
        elif 'runs past the end of the file' in why:
            loss.why += ' (torn: the file ends inside it)'
        self.lost.append(loss)
        self.open_loss = loss
        self.crc = None
        return nxt

    def run(self) -> None:
        if self.size < 8 or self.src.read(0, 8) != MAGIC:
            raise BagError(self.src.path, 'not an MCAP file (bad magic bytes at the start)')
        self._declare_from_summary()
        pos = 8
        size = self.size
        while pos < size:
            h = self._head(pos)
            if h is None:
                why, guess = 'the file ends inside a record header (torn)', None
            else:
                op, length = h
                end = pos + 9 + length
                why, guess = self._record(pos, op, length, end)
                if why is None:
                    if self.complete or self.torn_index:
                        return
                    self.last_op = op
                    pos = end
                    continue
            nxt = self._damage(pos, why, guess)
            if nxt is None:
                return
            pos = nxt
        self.ending = f'the file ends at byte {size} after its last record'

    def _declare_from_summary(self) -> None:
        """
        Return an intact summary repeats every Schema and Channel.

        Declare them first, so a channel whose record in the data section is damaged still
        has its messages copied.
        """
        if self.summary is None:
            return
        p, end = self.summary[0], self.summary[1]
        while p < end:
            op, length = REC.unpack_from(self.src.read(p, 9), 0)
            if op in (OP_SCHEMA, OP_CHANNEL):
                body = self.src.read(p + 9, length)
                try:
                    rec = (parse_schema if op == OP_SCHEMA else parse_channel)(body)
                except Damage:
                    pass
                else:
                    declare = self.sink.schema if op == OP_SCHEMA else self.sink.channel
                    declare(*rec, vouched=True)
            p += 9 + length

    def _torn_index(self, pos: int, length: int) -> bool:
        """
        Tell whether the record at ``pos`` is a Message Index cut by the end of the file.

        It must belong to the intact chunk before it: its fields agree with its length and nothing
        validates after it.
        """
        if self.open_loss is not None or self.last_op not in (OP_CHUNK, OP_MESSAGE_INDEX):
            return False
        head = self.src.read(pos + 9, 6)
        if len(head) < 6 or 6 + U32.unpack_from(head, 2)[0] != length or length % 16 != 6:
            return False
        return self._resync(pos + 1) is None

    def _record(self, pos: int, op: int, length: int, end: int):
        """
        Take the record at ``pos``.

        (None, None) if it validated, else (why, where the next record would start if only
        this one is bad).
        """
        if end > self.size:
            if op == OP_MESSAGE_INDEX and self._torn_index(pos, length):
                # the index of the intact chunk before it, cut by the end of the file: the
                # output gets its own index, nothing is lost
                self.ending = (f'the file ends at byte {self.size} inside the message index of '
                               'its last chunk')
                self.torn_index = True
                return None, None
            return f'record (opcode {op}) runs past the end of the file', None
        guess = end
        if op == OP_HEADER and pos == 8:
            body = self.src.read(pos + 9, length)
            try:
                _, p = read_string(body, 0)
                exact(body, read_string(body, p)[1])
            except Damage as exc:
                return f'header record: {exc}', guess
        elif op == OP_DATA_END:
            if length != 4:
                return 'data end record of the wrong length', guess
            body = self.src.read(pos + 9, 4)
            if not self._end_ok(pos, self.crc):
                return ('data end record not followed by a valid summary, footer or end of file '
                        'and its data CRC does not match', guess)
            (stored,) = U32.unpack_from(body, 0)
            if self.crc is not None and stored and stored != self.crc:
                self.crc_mismatch = True
            self.complete = True
            if self.summary is not None and self.summary[0] == pos + 13:
                then = 'a valid summary and footer)'
            elif pos + 13 == self.size:
                then = 'the end of the file)'
            else:
                then = 'a damaged summary, but the data CRC matches)'
            self.ending = 'the file was complete (data end, then ' + then
            return None, None
        elif op not in _DATA_OPS:
            return f'opcode {op} does not belong in the data section', guess
        elif length > MAX_CHUNK + (1 << 20):
            return f'record (opcode {op}) longer than any chunk recover accepts', guess
        else:
            body = self.src.read(pos + 9, length)
            try:
                self._take(pos, op, body)
            except Damage as exc:
                return f'{_OP_NAMES.get(op, op)} record: {exc}', guess
        if self.crc is not None:
            self.crc = zlib.crc32(body, zlib.crc32(REC.pack(op, length), self.crc))
        return None, None

    def _take(self, pos: int, op: int, body: bytes) -> None:
        sink = self.sink
        if op == OP_CHUNK:
            inner, msgs, decls = chunk_records(body)    # all validated: now hand them on
            sink.chunk(inner, msgs, decls)
            self.last_chunk = msgs
            if msgs:
                if self.open_loss is not None:
                    self.open_loss.after = min(m[1] for m in msgs)
                self.t_last = max(m[1] for m in msgs)
            self.open_loss = None
        elif op == OP_MESSAGE_INDEX:
            cid, n, t0, t1 = parse_message_index(body)
            if self.open_loss is not None and not self._indexes_last_chunk(cid, n, t0, t1):
                self.open_loss.index[pos] = (n, t0, t1)
        elif op == OP_SCHEMA:
            sink.schema(*parse_schema(body))
        elif op == OP_CHANNEL:
            sink.channel(*parse_channel(body))
        elif op == OP_METADATA:
            sink.metadata(*parse_metadata(body))
        elif op == OP_MESSAGE:
            if len(body) < MSG_FIXED:
                raise Damage('shorter than its fixed fields')
            cid, _seq, t, _pub = struct.unpack_from('<HIQQ', body, 0)
            sink.message(cid, t, body[MSG_FIXED:])
        elif op == OP_ATTACHMENT:
            parse_attachment(body)
            self.attachments += 1

    def _indexes_last_chunk(self, cid: int, n: int, t0, t1) -> bool:
        """
        Tell whether a Message Index read after damage describes the intact chunk before it.

        Same channel, count and stamps, not a lost chunk.
        """
        stamps = [m[1] for m in self.last_chunk if m[0] == cid]
        return bool(stamps) and (len(stamps), min(stamps), max(stamps)) == (n, t0, t1)

    # -- after the pass: what the damaged bytes held ------------------------------------------
    def settle(self) -> Optional[int]:
        """
        Fill in each loss's time range and message count.

        Return the file's own message count (its Statistics record) when its summary is
        intact.
        """
        total, indexed = None, False
        if self.summary is not None and self.summary[0] < self.summary[1]:
            starts = [x.start for x in self.lost]
            p, end = self.summary[0], self.summary[1]
            while p < end:
                op, length = REC.unpack_from(self.src.read(p, 9), 0)
                indexed = indexed or op == OP_CHUNK_INDEX
                if op in (OP_CHUNK_INDEX, OP_STATISTICS):
                    body = self.src.read(p + 9, length)
                    try:
                        if op == OP_STATISTICS:
                            need(body, 0, 8)
                            (total,) = U64.unpack_from(body, 0)
                        elif self.lost:
                            self._attribute(starts, body)
                    except (Damage, struct.error):
                        pass
                p += 9 + length
        for x in self.lost:
            x.indexed = indexed
        for x in self.lost:
            x.settle()
        return total

    def _attribute(self, starts: List[int], body: bytes) -> None:
        need(body, 0, 40)
        t0, t1, cstart, clen, n = struct.unpack_from('<QQQQI', body, 0)
        need(body, 36, n)
        offsets = {o for _, o in struct.iter_unpack('<HQ', body[36:36 + n])} if n % 10 == 0 \
            else set()
        k = bisect.bisect_right(starts, cstart + clen - 1) - 1     # last loss starting inside
        while k >= 0 and self.lost[k].end > cstart:
            x = self.lost[k]
            if x.start < cstart + clen:
                x.chunks += 1
                x.chunk_t = (t0, t1) if x.chunk_t is None else (min(x.chunk_t[0], t0),
                                                                max(x.chunk_t[1], t1))
                x.chunk_mi |= offsets
            k -= 1


_OP_NAMES = {OP_SCHEMA: 'schema', OP_CHANNEL: 'channel', OP_MESSAGE: 'message',
             OP_CHUNK: 'chunk', OP_MESSAGE_INDEX: 'message index', OP_METADATA: 'metadata',
             OP_ATTACHMENT: 'attachment'}


# ------------------------------------------------------------------------------------------
# Writing
# ------------------------------------------------------------------------------------------
class _Out:
    """
    Streams what the scan hands over into a :class:`BagWriter` on a temporary file next to ``out``.

    :meth:`finish` renames it into place, :meth:`abort` removes it.
    """

    def __init__(self, out: Path, force: bool):
        self.out, self.force = out, force
        self.part = out.with_name(f'{out.name}.recover-{os.getpid()}.part')
        self.w: Optional[BagWriter] = None
        self.schemas: Dict[int, Tuple[str, str]] = {}
        self.topics: Dict[int, Optional[str]] = {}
        self.drop_why: Dict[int, str] = {}      # channel id -> why its messages are dropped
        self.dropped: Dict[str, int] = {}       # why -> messages dropped
        self.n = 0
        self.saved_topics: set = set()          # the topics it wrote a message on
        self.vouched: Dict[tuple, tuple] = {}   # the summary's Schemas and Channels by id
        self.overruled: set = set()             # data-section records that contradict them
        self.t_first: Optional[int] = None
        self.t_last: Optional[int] = None
        self.run_record: Optional[Dict[str, str]] = None    # written by finish (its duration)
        self.offset = 0                 # log time - stamp, from the file's log_time record
        self.offset_problem: Optional[str] = None
        self.status_cid: Optional[int] = None
        self.statuses: List[Tuple[int, bytes]] = []        # (stamp, CDR) of /im/status

    def _writer(self) -> BagWriter:
        if self.w is None:
            try:
                self.w = BagWriter(self.out, force=self.force, part=self.part,
                                   close_at_exit=False, flush_wall_s=None)   # renamed when whole
            except OSError as exc:
                raise BagError(self.out, f'cannot write: {exc.strerror or exc}') from None
        return self.w

    def _overruled(self, key, rec, vouched: bool, what: str) -> bool:
        """
        Tell whether a declaration contradicts the summary's record of the same id.

        The summary's (declared first, ``vouched``) is kept: a record of the data section that
        differs from it was altered (one zeroed byte in a channel's topic name put its messages
        under a name nothing records, and recover said 0 messages lost).
        """
        if vouched:
            self.vouched[key] = rec
            return False
        known = self.vouched.get(key)
        if known is None or known == rec:
            return False
        self.overruled.add(what)
        return True

    def schema(self, sid, name, enc, vouched: bool = False) -> None:
        if self._overruled(('schema', sid), (name, enc), vouched, f'schema {sid}'):
            return
        self.schemas[sid] = (name, enc)

    def channel(self, cid, sid, topic, enc, meta, vouched: bool = False) -> None:
        known = self.vouched.get(('channel', cid))
        if self._overruled(('channel', cid), (sid, topic, enc, meta), vouched,
                           f'channel {cid} ({known[1] if known else topic})'):
            return
        name = self.schemas.get(sid, ('', ''))[0]
        why = (f'{topic}: message encoding {enc!r}, not cdr' if enc != 'cdr'
               else f'{topic}: its schema record was lost' if not name else None)
        if why is None:
            try:
                self._writer().add_topic(topic, name, qos=meta.get('offered_qos_profiles'))
            except ValueError as exc:     # its QoS metadata does not parse, ...: one line
                why = str(exc) if topic in str(exc) else f'{topic}: {exc}'
        self.topics[cid] = None if why else topic
        if topic == STATUS_TOPIC and not why:
            self.status_cid = cid
        if why:
            self.drop_why[cid] = why
            self.dropped.setdefault(why, 0)

    def message(self, cid, t, data) -> None:
        topic = self.topics.get(cid)
        if topic is None:
            why = self.drop_why.get(cid, f'channel id {cid}: its channel record was lost')
            self.dropped[why] = self.dropped.get(why, 0) + 1
            return
        self.w.write_serialized(topic, data, t)
        if cid == self.status_cid:
            self.statuses.append((t, bytes(data)))
        self.n += 1
        self.saved_topics.add(topic)
        if self.t_first is None or t < self.t_first:
            self.t_first = t
        if self.t_last is None or t > self.t_last:
            self.t_last = t

    def chunk(self, inner: bytes, msgs, decls) -> None:
        """
        Return a validated chunk's messages.

        Any Schema/Channel it declares comes in its place.
        """
        view = memoryview(inner)
        k = 0
        for at, op, rec in decls:
            if at > k:
                self._messages(view, msgs[k:at])
                k = at
            (self.schema if op == OP_SCHEMA else self.channel)(*rec)
        if k < len(msgs):
            self._messages(view, msgs[k:] if k else msgs)

    def _messages(self, view, msgs) -> None:
        topics = self.topics
        ws = self.w.write_serialized if self.w is not None else None
        status = self.status_cid
        saved = self.saved_topics.add
        n = 0
        for cid, t, a, b in msgs:
            topic = topics.get(cid)
            if topic is None:
                self.message(cid, t, view[a:b])
                continue
            ws(topic, view[a:b], t)
            saved(topic)
            if cid == status:
                self.statuses.append((t, bytes(view[a:b])))
            n += 1
        if n:
            self.n += n
            if n < len(msgs):
                msgs = [m for m in msgs if topics.get(m[0]) is not None]
            t0 = min(m[1] for m in msgs)
            t1 = max(m[1] for m in msgs)
            self.t_first = t0 if self.t_first is None else min(self.t_first, t0)
            self.t_last = t1 if self.t_last is None else max(self.t_last, t1)

    def to_stamps(self, lost) -> None:
        """
        Turn every time gathered so far from log times into the run's simulated stamps.

        Less the file's log-time offset (its ``log_time`` record; 0 without one, or when that
        record was lost — the times are then the file's log times, as said in the notes).
        """
        off = self.offset
        if not off:
            return

        def st(t):
            return None if t is None else t - off
        self.t_first, self.t_last = st(self.t_first), st(self.t_last)
        self.statuses = [(t - off, d) for t, d in self.statuses]
        for x in lost:
            x.t0, x.t1, x.before, x.after = st(x.t0), st(x.t1), st(x.before), st(x.after)

    def metadata(self, name, md) -> None:
        if name == LOG_TIME_RECORD:     # copied as is: the output keeps the file's log times
            try:
                self.offset = log_time_offset({name: md}, self.out)
            except BagError as exc:     # said in the notes: the times stay the file's log times
                self.offset = 0
                self.offset_problem = f'{exc.problem}; times below are log times, not stamps'
        if name == 'run':
            self.run_record = dict(md)      # written by finish, its duration what was saved
        elif name not in ('rosbag2', 'recovered_from'):
            self._writer().add_metadata(name, md)

    def finish(self, recovered_from: Dict[str, str],
               run_record: Optional[Dict[str, str]] = None) -> None:
        w = self._writer()
        if run_record is not None:
            w.add_metadata('run', run_record)
        w.add_metadata('recovered_from', recovered_from)
        w.close()

    def abort(self) -> None:
        if self.w is not None:
            try:
                self.w.discard()
            except OSError:
                pass
        try:
            os.unlink(self.part)
        except FileNotFoundError:
            pass


# ------------------------------------------------------------------------------------------
# The run's own record: how far it went, against what was saved
# ------------------------------------------------------------------------------------------
STATUS_TOPIC = '/im/status'
_END_STATES = ('finished', 'stopped', 'failed')


def _run_file(record: Optional[Dict[str, str]]) -> dict:
    """Return the ``run`` record's run file as a mapping ({} when absent or unreadable)."""
    if not record or 'yaml' not in record:
        return {}
    try:
        doc = yaml.safe_load(record['yaml'])
    except yaml.YAMLError:
        return {}
    return doc if isinstance(doc, dict) else {}


def run_end(statuses, run_file: dict) -> Tuple[Optional[int], str, bool]:
    """
    Return (stamp of the run's last step, where that comes from, proven) as the file knows it.

    Proven: the time master's final event (finished, stopped, failed) was saved, with its step.
    Else the run file's ``duration`` (the run was to end there; it may have ended earlier).
    Else (None, '', False): unknown.
    """
    from rclpy.serialization import deserialize_message   # heavy: rclpy, only for a run's end
    cls = cdr.message_class('diagnostic_msgs/msg/DiagnosticArray') if statuses else None
    for t, data in reversed(statuses):
        try:
            msg = deserialize_message(data, cls)
        except Exception:       # noqa: BLE001 - an undecodable status tells nothing
            continue
        for st in msg.status:
            values = {kv.key: kv.value for kv in st.values}
            if values.get('time_master') == 'true' and st.message in _END_STATES:
                period = int(values.get('T_s_ns', 0) or 0)
                step = values.get('step')
                end = int(step) * period if step is not None and period else t
                return end, f"the plant's final event ({st.message} at step {step})", True
    try:
        duration = float(run_file.get('duration'))
    except (TypeError, ValueError):
        return None, '', False
    return s_to_ns(duration), "its run file's duration; it may have ended earlier", False


def missing_tail(saved_last: Optional[int], lost_last: Optional[int], statuses,
                 run_file: dict) -> Optional[dict]:
    """
    Return the tail of the run after what was saved (None if the file proves there is none).

    The tail starts after the last saved stamp (or the last stamp of a damaged range at the end
    of the file, whichever is later) and runs to the end of the run as :func:`run_end` knows it
    (``t1_ns`` None: unknown).
    """
    end, source, proven = run_end(statuses, run_file)
    last = max((t for t in (saved_last, lost_last) if t is not None), default=None)
    if proven and last is not None and last >= end:
        return None
    t0 = last
    if end is not None and last is not None and end <= last:
        end, source = None, (source + ', but the file holds later stamps')

    def s(t):
        return f'{ns_to_s(t):.9f}'
    start = 'the start' if t0 is None else s(t0)
    if end is None:
        text = (f'lost t = {start} .. end of run (unknown): the writer did not close the file, '
                'and nothing in it says how long the run went on')
    else:
        span = f'; {ns_to_s(end - (t0 or 0)):.3f} s' if t0 is not None else ''
        text = (f'lost t = {start} .. end of run ({s(end)} s per {source}{span}): the writer '
                'did not close the file')
    return {'t0_ns': t0, 't1_ns': end, 'proven_end': proven, 'source': source, 'text': text}


def saved_run_record(record: Dict[str, str], saved_last: Optional[int]) -> Dict[str, str]:
    """Return the ``run`` record with its ``duration`` set to what was saved (its last stamp)."""
    doc = _run_file(record)
    if not doc or 'duration' not in doc:
        return record
    doc['duration'] = round(ns_to_s(saved_last or 0), 9)
    out = dict(record)
    out['yaml'] = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=100)
    return out


def source_of(path) -> Path:
    """Return the file to salvage: ``path``, or the ``<path>.part`` a killed writer left."""
    p = Path(path)
    if not p.exists() and partial_path(p).exists():
        return partial_path(p)
    return p


def default_output(path) -> Path:
    """``run.mcap`` and ``run.mcap.part`` -> ``run.recovered.mcap``."""
    p = Path(path)
    name = p.name[:-len('.part')] if p.name.endswith('.part') else p.name
    stem = name[:-len('.mcap')] if name.endswith('.mcap') else name
    return p.with_name(stem + '.recovered.mcap')


def recover(path, out: Optional[str] = None, force: bool = False) -> dict:
    """
    Rewrite the intact records of ``path`` into ``out``.

    Returns counts, paths and what was lost (``lost``: one line each; ``lost_ranges``: the same
    as dicts).

    ``path`` may name a recording whose writer was killed: its data is then in ``<path>.part``
    (see :class:`~im_recording.bag.BagWriter`), which is read instead.
    """
    src = source_of(path)
    if not src.exists():
        raise BagError(src, 'no such file')
    if src.is_dir():
        raise BagError(src, 'is a directory; expected an .mcap file')
    out = Path(out) if out else default_output(path)
    check_output(out, [p for p in (src, Path(path)) if p.exists()], force,
                 what='recovered file')
    source = _Source(src)
    sink = _Out(out, force)
    try:
        scan = _Scan(source, sink)
        try:
            scan.run()
        except OSError as exc:          # the output: BagWriter writing a chunk
            raise BagError(out, f'cannot write: {exc.strerror or exc}') from None
        total = scan.settle()
        sink.to_stamps(scan.lost)       # from here on: simulated stamps, as the run knew them
        if sink.n == 0 and not any(t for t in sink.topics.values()):
            raise BagError(src, 'nothing to recover (no intact channel or message; '
                           + (scan.lost[0].text() if scan.lost else scan.ending) + ')')
        lost = [x.text() for x in scan.lost]
        notes = _notes(scan, sink)
        dropped = sum(sink.dropped.values())    # read intact, but not copied (said in notes)
        n_lost = (total - sink.n if total is not None
                  else sum(x.messages for x in scan.lost) + dropped
                  if all(x.messages is not None for x in scan.lost) else None)
        run_file = _run_file(sink.run_record)
        tail = None
        if not scan.complete:       # the writer did not close it: how far did the run go on?
            lost_last = max((x.t1 for x in scan.lost if x.t1 is not None), default=None)
            tail = missing_tail(sink.t_last, lost_last, sink.statuses, run_file)
            if tail is not None:
                lost.append(tail['text'])
        whole = not scan.lost and not scan.crc_mismatch and tail is None and not dropped
        reason = _reason(scan, whole, tail, dropped, total, n_lost)
        at_least = None
        if tail is not None and total is None and n_lost is not None:
            at_least, n_lost = n_lost, None     # the tail's messages are not counted
        run_record = sink.run_record
        recovered_from = {'path': str(src), 'reason': reason, 'lost': '; '.join(lost + notes),
                          'messages_lost': '' if n_lost is None else str(n_lost)}
        if at_least is not None:
            recovered_from['messages_lost_at_least'] = str(at_least)
        if tail is not None:
            recovered_from['lost_tail_ns'] = '-'.join(
                '' if tail[k] is None else str(tail[k]) for k in ('t0_ns', 't1_ns'))
        if run_record is not None and not whole and 'duration' in run_file:
            recovered_from['run_duration_s'] = str(run_file['duration'])
            run_record = saved_run_record(run_record, sink.t_last)
        try:
            sink.finish(recovered_from, run_record)
        except OSError as exc:
            raise BagError(out, f'cannot write: {exc.strerror or exc}') from None
    except BaseException:
        sink.abort()
        raise
    finally:
        source.close()
    return {'input': str(src), 'output': str(out), 'messages': sink.n,
            'topics': len(sink.saved_topics),
            'complete': scan.complete and whole, 'whole': whole, 'reason': reason,
            'lost': lost, 'notes': notes, 'lost_ranges': [x.as_dict() for x in scan.lost],
            'messages_lost': n_lost, 'messages_lost_at_least': at_least,
            'messages_in_file': total, 'lost_tail': tail,
            'first_stamp_ns': sink.t_first, 'last_stamp_ns': sink.t_last}


def _notes(scan, sink) -> List[str]:
    """Return what was read intact but not copied as it was (one line each)."""
    notes = []
    if scan.crc_mismatch:
        notes.append('the data section CRC does not match although every record validated: '
                     'a record outside the chunks, or the stored CRC, was altered (kept as '
                     'read)')
    for why, n in sorted(sink.dropped.items()):
        notes.append(f'{n} message(s) not copied ({why})')
    if sink.offset_problem:
        notes.append(sink.offset_problem)
    if scan.attachments:
        notes.append(f'{scan.attachments} attachment(s) not copied')
    if sink.overruled:
        notes.append(', '.join(sorted(sink.overruled)) + ": the data section's record "
                     "differs from the summary's, which was kept")
    return notes


def _reason(scan, whole: bool, tail, dropped: int, total, n_lost) -> str:
    """Return the recovery's one-line reason: how the file ended and what of it was lost."""
    if whole:
        return scan.ending + ('' if scan.complete else
                              " (no data end, but the run's final event and every stamp up "
                              'to it are in the file)') + '; nothing lost'
    if tail is not None and not scan.lost and not scan.crc_mismatch and not dropped:
        return ('the writer did not close the file: ' + scan.ending + '; the tail of the '
                'run after the last saved message is lost')
    reason = (f'{len(scan.lost)} damaged range(s) skipped ('
              f'{sum(x.end - x.start for x in scan.lost)} bytes)' if scan.lost
              else 'data section CRC mismatch' if scan.crc_mismatch
              else f'{dropped} message(s) not copied')
    if total is not None:
        reason += f', {n_lost} of {total} messages lost'
    elif n_lost is not None and tail is not None:   # and the tail's, not counted
        reason += f', at least {n_lost} messages lost'
    elif n_lost is not None:
        reason += f', {n_lost} messages lost'
    else:
        reason += ', number of messages lost unknown'
    if tail is not None:
        reason += ', and the tail of the run after the last saved message'
    return reason


def load_salvaged(path, trace: Optional[str] = None):
    """
    Return (the :class:`~im_recording.recorded_run.RecordedRun` of what was saved, its recovery).

    For a recording whose writer failed or was killed (``path`` or its ``.part``): its intact
    records are recovered into a temporary directory, read by
    :func:`~im_recording.recorded_run.load_run` (the figures of every step the file holds, the
    ``recovered_from`` record) and removed; the input is untouched. :class:`BagError` when nothing
    can be salvaged.
    """
    with tempfile.TemporaryDirectory(prefix='im_salvage_') as d:
        out = Path(d) / 'salvaged.mcap'
        r = recover(path, str(out))
        run = load_run(out, trace=trace)
    run.path = r['input']
    return run, r


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='recover', description='Salvage the intact part of a '
                                 'truncated or damaged MCAP recording into a new, valid file.')
    ap.add_argument('bag')
    ap.add_argument('-o', '--out', default=None)
    ap.add_argument('--force', action='store_true', help='overwrite the output file')
    a = parse_args(ap, argv)
    try:
        with StopSignals(raise_=True):
            r = recover(a.bag, a.out, a.force)
    except (BagError, FileExistsError, OSError) as exc:
        return cli_error('recover', exc)
    except KeyboardInterrupt as exc:
        name = getattr(exc, 'signame', 'SIGINT')
        print(f'recover: interrupted by {name}; nothing written', file=sys.stderr)
        return exit_code_for(name)
    for line in r['lost'] + r['notes']:
        print(f'recover: {line}', file=sys.stderr)

    def s(t):
        return f'{ns_to_s(t):.9f}' if t is not None else '-'
    print(f"recover: saved {r['messages']} messages on {r['topics']} topics "
          f"(t = {s(r['first_stamp_ns'])} .. {s(r['last_stamp_ns'])} s) into {r['output']}; "
          f"{r['reason']}")
    return 0 if r['whole'] else 1


if __name__ == '__main__':
    sys.exit(main())
