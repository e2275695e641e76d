"""Cost of the graph's message tags (docs/security.md): signing and checking one lock-step message,
against packing it, and per step of the graph (plant 2 + controller 1 + observer 1 signed; 2 + 2 +
3 checks in the plant, controller and observer, 4 in the recorder).

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
    n = 20000 if quick else 200000
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
            'auth_per_step_us': (4 * sign + 11 * verify) * 1e6,
            'auth_hmac_sha256_us': sha * 1e6, 'auth_blake2s_keyed_us': b2 * 1e6}


if __name__ == '__main__':
    for k, v in run('--quick' in sys.argv).items():
        print(f'{k:32s} {v:10.3f}')
