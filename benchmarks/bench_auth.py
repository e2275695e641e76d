"""
Cost of the graph's message tags (docs/security.md).

Signing and checking one lock-step message, against packing it, and per step of the graph (5
signed: plant 2, controller, observer, adapter 1 each; 11 checked: plant 1, controller 3, observer
3, adapter 4; a recorder checks 5 more).

``hmac`` over SHA-256 is the standard library's other keyed MAC; BLAKE2s with a key is a MAC by
construction and the faster of the two here (both rows below), so the stack uses it.
"""
from __future__ import annotations

import hashlib
import hmac
import os
import sys
import time

from im_common.auth import Signer
from im_common.conversions import Vector3Out

TOPIC = '/im/command/voltage'


def _per_call(fn, n: int) -> float:
    t0 = time.perf_counter()
    for i in range(n):
        fn(i)
    return (time.perf_counter() - t0) / n


def run(quick: bool = False) -> dict:
    n = 2000 if quick else 200000
    s = Signer(os.urandom(32), 'run1')
    out = Vector3Out(Signer.frame('alphabeta'))
    pack = _per_call(lambda i: out.fill(i, 1.0, 2.0), n)
    packed = out.fill(5, 1.0, 2.0)
    sign = _per_call(lambda i: s.sign(TOPIC, packed), n)
    signed = s.sign(TOPIC, packed)
    verify = _per_call(lambda i: s.verify(TOPIC, signed), n)
    key = os.urandom(32)
    sha = _per_call(lambda i: hmac.new(key, signed, hashlib.sha256).digest(), n)
    b2 = _per_call(lambda i: hashlib.blake2s(signed, key=key, digest_size=16).digest(), n)
    return {'auth_pack_us': pack * 1e6, 'auth_sign_us': sign * 1e6, 'auth_verify_us': verify * 1e6,
            'auth_per_step_us': (5 * sign + 11 * verify) * 1e6,
            'auth_hmac_sha256_us': sha * 1e6, 'auth_blake2s_keyed_us': b2 * 1e6}


if __name__ == '__main__':      # the table and JSON come from the driver
    from run_all import main
    sys.exit(main(['--only', 'auth'] + sys.argv[1:]))
