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


def _batches():
    """Return JointState batches: one layout (tags differ), layouts mixed (names, counts)."""
    signer = Signer(bytes(32), 'run')
    shaft = JointStateOut([T.SHAFT_JOINT], Signer.frame(''))
    est = JointStateOut(T.ESTIMATE_NAMES, Signer.frame(''))
    ref = JointStateOut([T.SHAFT_JOINT], Signer.frame(''))     # the reports are signed too
    power = JointStateOut(T.POWER_NAMES, Signer.frame(''))
    one = [signer.sign(T.MEAS_SHAFT, shaft.fill(k * 100_000, (0.1 * k,), (-2.0 * k,)))
           for k in range(7)]
    named = [est.fill(k * 100_000, [1.0 + k] * len(T.ESTIMATE_NAMES)) for k in range(5)]
    refs = [signer.sign(T.REF_SHAFT, ref.fill(k * 100_000, (0.5 * k,), (1.5,), (2.5 * k,)))
            for k in range(4)]
    truth = [signer.sign(T.TRUTH_POWER, power.fill(k * 1_000_000, [0.25 * k] * len(T.POWER_NAMES)))
             for k in range(6)]
    mixed_counts = refs[:2] + [ref.fill(9, (1.0,), (), (3.0,)), ref.fill(10, (), (2.0,), ())]
    mixed_names = named[:2] + [pack_joint_state(0, 7, ('R_r', 'x'), (5.0, 6.0), (), ()),
                               pack_joint_state(0, 8, ('R_r',), (), (), ())]
    return [(T.MEAS_SHAFT, one), (T.ADAPT_ESTIMATE, named), (T.REF_SHAFT, refs),
            (T.TRUTH_POWER, truth), (T.REF_SHAFT, mixed_counts), (T.ADAPT_ESTIMATE, mixed_names),
            (T.TRUTH_PARAMS, [pack_joint_state(0, 1, ('a', 'b', 'a'), (1.0,), (), ())])]


@pytest.mark.parametrize('topic, payloads', _batches())
def test_batch_joint_state_decoding_equals_message_by_message(topic, payloads, monkeypatch):
    """The one-layout batch decoder of the recording/summary gives what decoding each gives."""
    import numpy as np

    from im_common import cdr
    from im_recording import recorded_run as run
    fast = run.decode_topic(topic, payloads)
    monkeypatch.setattr(cdr, 'joint_state_batch', lambda _payloads: None)
    slow = run.decode_topic(topic, payloads)
    np.testing.assert_array_equal(fast[0], slow[0])
    assert list(fast[1]) == list(slow[1])
    for key in slow[1]:
        np.testing.assert_array_equal(fast[1][key], slow[1][key], err_msg=key)
        assert fast[1][key].dtype == slow[1][key].dtype


def test_batch_joint_state_decoding_takes_one_layout_in_one_read():
    """A batch of one layout is read by the batch decoder (what keeps the summary tap cheap)."""
    from im_common.cdr import joint_state_batch
    for topic, payloads in _batches()[:4]:
        assert joint_state_batch(payloads) is not None, topic
    assert joint_state_batch(_batches()[4][1]) is None
    assert joint_state_batch(_batches()[5][1]) is None


@pytest.mark.parametrize('frame_id', ['', 'plant|' + 'ab' * 16])
def test_batch_vector3_decoding_equals_message_by_message(frame_id):
    """One read of a batch of one layout gives each payload's own stamp and values."""
    import numpy as np

    from im_common import cdr
    payloads = [cdr.pack_vector3_stamped(k // 3, 7 * k, 0.5 * k, -k, 2.0 ** -k, frame_id=frame_id)
                for k in range(9)]
    st, x, y, z = cdr.vector3_stamped_batch(payloads)
    each = [cdr.decode_vector3_stamped(p) for p in payloads]
    np.testing.assert_array_equal(st, [s * 1_000_000_000 + n for s, n, *_ in each])
    for col, got in zip(zip(*each), (None, None, x, y, z)):
        if got is not None:
            np.testing.assert_array_equal(got, col)
    # a frame id of another length in the batch: no common layout, decoded one by one
    assert cdr.vector3_stamped_batch(payloads + [cdr.pack_vector3_stamped(0, 0, 1, 2, 3, 'x')]) \
        is None
