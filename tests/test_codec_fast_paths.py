"""
The hot-path codecs give exactly what the general CDR code gives.

The hot-path codecs (one struct call per message) give exactly what the general CDR code gives, for
every frame-id length (its padding) and sequence-length combination, and a truncated payload is a
CdrError naming the type, as before.
"""
from __future__ import annotations

from im_common import topics as T
from im_common.auth import Signer
from im_common.cdr import CdrError, decode_vector3_stamped, pack_joint_state
from im_common.conversions import JointStateOut, Vector3Out, xy_in
import pytest

FRAMES = ['', 'a', 'ab', 'abc', 'abcdefg', 'abcdefgh', 'alphabeta', Signer.frame('alphabeta'),
          Signer.frame('')]


@pytest.mark.parametrize('frame', FRAMES)
def test_xy_in_equals_the_general_decoder(frame):
    for ns in (0, 100_000, 123_456_789_012):
        data = Vector3Out(frame).fill(ns, 1.5, -2.5, 3.25)
        sec, nsec, x, y, _ = decode_vector3_stamped(data)
        assert xy_in(data) == (sec * 1_000_000_000 + nsec, (x, y)) == (ns, (1.5, -2.5))


def test_xy_in_refuses_a_truncated_payload_with_a_cdr_error():
    data = Vector3Out(Signer.frame('alphabeta')).fill(5, 1.0, 2.0)
    for cut in (0, 4, 12, 20, len(data) - 1):
        with pytest.raises(CdrError, match='Vector3Stamped'):
            xy_in(data[:cut])


@pytest.mark.parametrize('frame', FRAMES)
@pytest.mark.parametrize('names, seqs', [
    ((T.SHAFT_JOINT,), ((0.5,), (1.5,), ())),
    ((T.SHAFT_JOINT,), ((0.5,), (1.5,), (2.5,))),
    (T.ESTIMATE_NAMES, (tuple(0.5 + i for i in range(len(T.ESTIMATE_NAMES))), (), ())),
    (T.ENERGY_NAMES, (tuple(float(i) for i in range(len(T.ENERGY_NAMES))), (), ())),
    (('a', 'bb', 'ccc'), ((), (), ())),
])
def test_joint_state_out_equals_pack_joint_state(frame, names, seqs):
    out = JointStateOut(names, frame)
    for ns in (0, 123_456_789_012):
        sec, nsec = divmod(ns, 1_000_000_000)
        assert out.fill(ns, *seqs) == pack_joint_state(sec, nsec, names, *seqs, frame)
