"""
The real plant's compiled period against its pure-Python reference (im_common.real_plant_kernel).

Each run is stepped twice in lock-step with the same commands, once with ``use_kernel`` (numba)
and once with the pure-Python path of ``RealPlant._solve`` (docs/plant.md §1, §9): after every
period every state component and energy integral, the DC link, the switching losses, the ripple
and the temperatures agree to 1e-12 (relative; absolute 1e-12 near 0). The runs reach the
kernel's hand-backs: currents changing sign at an interval boundary (the period again with
explicit dead bands, compiled too) and repeated eigenvalues (RK4, in Python).
"""
import math

from im_common import real_plant_kernel
from im_common.loads import LinearLoad
from im_common.params import THESIS_MOTOR
from im_common.plant_sim import PlantSimulator
from im_common.real_plant import RealPlant
from im_common.saturation import power_law_fit
import numpy as np
import pytest

pytestmark = pytest.mark.skipif(not real_plant_kernel.available, reason='numba not installed')

P = THESIS_MOTOR
T_S = 1e-4
F_SW = 1e4
REL = ABS = 1e-12
#: every inverter effect: dead time, on-state drop and resistance, switching losses, DC link
INVERTER = {'V_dc': 330.0, 'pwm_frequency': F_SW, 'deadtime': 2e-6, 'v_on': 1.0, 'r_on': 0.03,
            'e_sw': 2.0e-4, 'v_sw': 300.0, 'i_sw': 10.0, 'C_dc': 1e-3, 'V_chopper': 380.0,
            'R_chopper': 30.0}
SATURATION = {'law': 'power', 'beta': power_law_fit(0.55, 0.875, 7.0), 'S': 7.0}
THERMAL = {'C_s': 50.0, 'R_th_s': 0.5, 'C_r': 20.0, 'R_th_r': 0.5}
TRUTH = ('E_switching', 'P_switching', 'V_dc', 'E_source', 'E_chopper', 'i_ripple_pp',
         'P_inverter', 'T_stator', 'T_rotor')


@pytest.fixture
def statuses(monkeypatch):
    """
    Count the statuses the kernels return over a test.

    [DONE, SIGN_CHANGE, FALLBACK] of ``period`` (resolved dead bands), then [DONE, -, FALLBACK]
    of ``explicit`` (explicit dead bands: after a sign change, or a zero current at the start).
    """
    count = [0] * 6

    def counted(name, offset):
        compiled = getattr(real_plant_kernel, name)

        def call(*args):
            out = compiled(*args)
            count[offset + out[0]] += 1
            return out
        monkeypatch.setattr(real_plant_kernel, name, call)

    counted('period', 0)
    counted('explicit', 3)
    return count


def _close(a, b, what):
    assert a == pytest.approx(b, rel=REL, abs=ABS, nan_ok=True), what


def _pair(**kw):
    """Return (compiled, reference): the same plant, the kernel on and off."""
    fast = PlantSimulator(**kw)
    ref = PlantSimulator(**kw)
    assert isinstance(fast.real, RealPlant) and fast.real.use_kernel
    ref.real.use_kernel = False
    return fast, ref


def _lockstep(fast, ref, command, n):
    """Step both n periods with command(k), comparing after every period."""
    for k in range(n):
        v = command(k)
        fast.step(*v)
        ref.step(*v)
        assert len(fast.x) == len(ref.x)
        for j, (a, b) in enumerate(zip(fast.x, ref.x)):
            _close(a, b, (k, j))
        _close(fast.v_applied[0], ref.v_applied[0], (k, 'v_alpha'))
        _close(fast.v_applied[1], ref.v_applied[1], (k, 'v_beta'))
        real, want = fast.real, ref.real
        _close(real.V, want.V, (k, 'V_dc'))
        _close(real.E_switching, want.E_switching, (k, 'E_switching'))
        _close(real.ripple, want.ripple, (k, 'ripple'))
        assert real._end_poles == want._end_poles, k
        assert (fast.trip is None) == (ref.trip is None), k
    tf, tr = fast.truth(), ref.truth()
    for key in TRUTH:
        if key in tr:
            _close(tf[key], tr[key], key)


def _dol(V_hat=200.0, f=60.0):
    def command(k):
        ang = 2.0 * math.pi * f * k * T_S
        return V_hat * math.cos(ang), V_hat * math.sin(ang)
    return command


def test_every_block_on_direct_on_line_start_equals_the_reference(statuses):
    """The start of test_energy_books_close_with_every_block_on, 3000 periods, switching losses."""
    m = P.with_values(rated_voltage_rms_line=220.0)
    fast, ref = _pair(schedule=m, load=LinearLoad(1.0, 0.001), T_s=T_S, inverter=INVERTER,
                      saturation=SATURATION, thermal=THERMAL, iron_loss=True,
                      sensors={'encoder_lines': 2048, 'adc_bits': 12})
    _lockstep(fast, ref, _dol(), 3000)
    assert fast.x[5] > 100.0 and fast.real.E_switching > 0.0 and fast.x[9] > 0.0
    assert statuses[0] > 2500 and statuses[1] > 20, statuses   # sign changes handed back
    assert statuses[3] >= statuses[1], statuses


@pytest.mark.parametrize('update, exponent', [('single', 1.0), ('double', 2.0)])
def test_booked_core_loss_and_double_update_equal_the_reference(statuses, update, exponent):
    """No iron loss in the model: the booked (k_h + k_e f) f |ψ|^n; single and double update."""
    inv = dict(INVERTER, update=update)
    fast, ref = _pair(schedule=P, load=LinearLoad(1.0, 0.001),
                      T_s=T_S if update == 'single' else 0.5 * T_S, inverter=inv,
                      core_loss_exponent=exponent)
    _lockstep(fast, ref, _dol(V_hat=150.0, f=40.0), 2000)
    assert fast.x[9] > 0.0 and statuses[0] > 1500 and statuses[1] > 5, statuses


def test_a_small_current_at_standstill_changes_sign_often(statuses):
    """Locked rotor, a slow 2 V command: the dead bands' signs flip at many boundaries."""
    inv = {k: v for k, v in INVERTER.items() if k not in ('C_dc', 'V_chopper', 'R_chopper')}
    fast, ref = _pair(schedule=P, load=None, T_s=T_S, inverter=inv, locked_rotor=True)
    _lockstep(fast, ref, _dol(V_hat=2.0, f=5.0), 2000)
    assert statuses[1] > 100 and statuses[3] >= statuses[1], statuses


def test_ideal_source_with_saturation_and_iron_loss_equals_the_reference(statuses):
    """No inverter: the command held, the period's own one-vector table (not _UNIT)."""
    fast, ref = _pair(schedule=P, load=LinearLoad(1.0, 0.001), T_s=T_S, saturation=SATURATION,
                      iron_loss=True, thermal=THERMAL)
    _lockstep(fast, ref, _dol(), 2000)
    assert statuses[0] >= 2000 and statuses[1] == 0, statuses


def test_repeated_eigenvalues_hand_back_to_rk4(statuses):
    """test_real_plant's repeated eigenvalues: the kernel hands the periods back (FALLBACK)."""
    th = P.L_sr / P.L_r
    L_M = P.L_sr * th
    L_sig = P.L_s - L_M
    R_R = th * th * P.R_r
    R_s = R_R * (1.0 + L_sig / L_M)
    omega = math.sqrt(R_s / L_sig * R_R / L_sig)
    m = P.with_values(R_s=R_s, J=1e9)
    neutral = {'C_s': 1e9, 'R_th_s': 1.0, 'C_r': 1e9, 'R_th_r': 1.0, 'alpha_s': 0.0,
               'alpha_r': 0.0}
    fast, ref = _pair(schedule=m, load=None, T_s=T_S, thermal=neutral,
                      x0=(0.3, 0.1, 0.2, 0.05, 0.0, omega))
    _lockstep(fast, ref, lambda k: (50.0, 20.0), 50)
    assert statuses[2] > 0, statuses


def test_a_trip_shorts_the_stator_in_both(statuses):
    """After an over-current trip both integrate the shorted stator (no kernel: no events)."""
    fast, ref = _pair(schedule=P, load=LinearLoad(1.0, 0.001), T_s=T_S, inverter=INVERTER,
                      current_trip=5.0)
    _lockstep(fast, ref, _dol(), 2000)
    assert fast.trip is not None and fast.trip == ref.trip
    assert statuses[0] < 1000 and statuses[3] > 1000, statuses   # the shorted stator: a plan


@pytest.mark.parametrize('update', ['single', 'double'])
def test_compiled_events_are_the_reference_events(update):
    """Random duties, carries and signs: the same instants and bits, in the same order."""
    rng = np.random.default_rng(46)
    inv = dict(INVERTER, update=update, deadtime=3e-6)
    sim = PlantSimulator(P, None, T_s=T_S if update == 'single' else 0.5 * T_S, inverter=inv)
    plant = sim.real
    T_c = plant.inverter.T_c
    t_d = plant.inverter.deadtime
    for _ in range(3000):
        d = tuple(float(x) for x in rng.choice(
            [rng.uniform(-0.1, 1.1), 0.0, 1.0, rng.uniform(0.0, 0.02), rng.uniform(0.98, 1.0)],
            size=3))
        half = int(rng.integers(2)) if update == 'double' else 0
        signs = tuple(float(x) for x in rng.choice([-1.0, 1.0], size=3))
        plant._carry = tuple(float(x) for x in rng.choice(
            [0.0, t_d, rng.uniform(0.0, t_d)], size=3))
        want, want_code = plant._events(d, half, signs)
        got = real_plant_kernel.events_buffer()
        n, code = real_plant_kernel.events(got, d[0], d[1], d[2], half, T_c, sim.T_s, t_d,
                                           *plant._carry, *signs)
        assert code == want_code
        assert [(t, int(b)) for t, b in got[:n].tolist()] == want


def test_one_compiled_signature_each():
    """Every call RealPlant makes has the types warm() compiled: nothing compiles mid-run."""
    real_plant_kernel.warm()
    for kw in ({'inverter': INVERTER, 'saturation': SATURATION, 'iron_loss': True},
               {'inverter': dict(INVERTER, deadtime=0.0, v_on=0.0)}, {'iron_loss': True}):
        sim = PlantSimulator(P, LinearLoad(1.0, 0.001), T_s=T_S, **kw)
        for k in range(200):
            sim.step(*_dol()(k))
    assert len(real_plant_kernel.period.signatures) == 1
    assert len(real_plant_kernel.events.signatures) == 1
    assert len(real_plant_kernel.explicit.signatures) == 1
