"""
The real plant's compiled period against its pure-Python reference (im_plant.real_plant_kernel).

Each run is stepped twice in lock-step with the same commands, once with ``use_kernel`` (numba:
the whole period in one call, :func:`real_plant_kernel.step`) and once with the pure-Python path
of ``RealPlant._solve`` (docs/plant.md §1, §9): after every period every state component and
energy integral, the mean voltage, the measurement (encoder, ADC), the state's currents, the DC
link, the switching losses, the ripple and the temperatures agree to 1e-12 (relative; absolute
1e-12 near 0), and so does the whole truth at the end. The runs reach the kernel's paths and
hand-backs: currents changing sign at an interval boundary (the period again with explicit dead
bands, compiled too) and repeated eigenvalues (RK4, in Python).
"""
import math

from im_common.loads import (ConstantLoad, LinearLoad, PendulumLoad, ScheduleLoad, StepLoad)
from im_common.params import THESIS_MOTOR
from im_common.saturation import power_law_fit
from im_plant import real_plant_kernel
from im_plant.plant_sim import PlantSimulator
from im_plant.real_plant import RealPlant
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
#: the statuses the kernels returned in the test running now (the fixture ``statuses``)
_COUNT = []


@pytest.fixture
def statuses(monkeypatch):
    """
    Count the statuses the kernels return over a test.

    [DONE, SIGN_CHANGE, FALLBACK] of ``period`` (resolved dead bands), then [DONE, -, FALLBACK]
    of ``explicit`` (explicit dead bands: after a sign change, or a zero current at the start):
    in the whole-period kernel (its counters, added by :func:`_lockstep`) and in the periods it
    hands back (the reference path with the partial kernels, counted as they return).
    """
    count = [0] * 6
    _COUNT[:] = [count]
    real_plant_kernel.warm()                    # compiled before the counting wrappers

    def counted(name, offset):
        compiled = getattr(real_plant_kernel, name)

        def call(*args):
            out = compiled(*args)
            count[offset + out[0]] += 1
            return out
        monkeypatch.setattr(real_plant_kernel, name, call)

    counted('period', 0)
    counted('explicit', 3)
    yield count
    _COUNT.clear()


def _close(a, b, what):
    assert a == pytest.approx(b, rel=REL, abs=ABS, nan_ok=True), what


def _pair(**kw):
    """Return (compiled, reference): the same plant, the kernel on and off."""
    fast = PlantSimulator(**kw)
    ref = PlantSimulator(**kw)
    assert isinstance(fast.real, RealPlant) and fast.real.use_kernel
    ref.real.use_kernel = False
    return fast, ref


def _same(a, b, what):
    """Compare two measurements, tuples of floats or truths (1e-12; strings equal)."""
    if isinstance(b, dict):
        assert sorted(a) == sorted(b), what
        for key in b:
            _same(a[key], b[key], (what, key))
    elif isinstance(b, str):
        assert a == b, what
    elif isinstance(b, (tuple, list)):
        assert len(a) == len(b), what
        for j, (p, q) in enumerate(zip(a, b)):
            _same(p, q, (what, j))
    elif hasattr(b, '__dataclass_fields__'):
        for key in b.__dataclass_fields__:
            _same(getattr(a, key), getattr(b, key), (what, key))
    else:
        _close(a, b, what)


def _lockstep(fast, ref, command, n, truth_every=0):
    """
    Step both n periods with command(k), comparing after every period (the truth every so many).

    The measurement, the stator and state currents are asked as the drive asks them, after each
    period; the whole truth (every key) at the end and every ``truth_every`` periods.
    """
    for k in range(n):
        v = command(k)
        fast.step(*v)
        ref.step(*v)
        _same(fast.measure(), ref.measure(), (k, 'measure'))
        _same(fast.stator_currents(), ref.stator_currents(), (k, 'stator_currents'))
        _same(fast.state_currents(), ref.state_currents(), (k, 'state_currents'))
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
        assert fast.trip == ref.trip, k
        if truth_every and k % truth_every == 0:
            _same(fast.truth(), ref.truth(), (k, 'truth'))
    _same(fast.truth(), ref.truth(), 'truth')
    w = fast.real._w
    if _COUNT and w is not None:                # the whole-period kernel's paths
        K = real_plant_kernel
        _COUNT[0][0] += int(w[K.N_EV])
        _COUNT[0][1] += int(w[K.N_SIGN])
        _COUNT[0][3] += int(w[K.N_EXPL])


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


SENSORS = {'encoder_lines': 1024, 'speed_window': 7, 'adc_bits': 11, 'current_range': 30.0,
           'current_offset': [0.05, -0.02, 0.01], 'current_gain': [1.01, 0.99, 1.0],
           'vdc_range': 800.0}
TABLE = {'table': [[0.2, 0.5], [0.4, 1.1], [0.55, 2.0], [0.7, 4.0]]}


@pytest.mark.parametrize('load', [
    None, ConstantLoad(1.5), PendulumLoad(2.0), StepLoad(0.05, 0.5, 2.5),
    ScheduleLoad(((0.0, 0.5), (0.04, 2.0), (0.04, 1.0), (0.08, 3.0)))])
def test_every_load_kind_with_a_table_curve_and_real_sensors(statuses, load):
    """The loads the kernel evaluates itself, the table curve, encoder and ADC with offsets."""
    fast, ref = _pair(schedule=P, load=load, T_s=T_S, inverter=INVERTER, saturation=TABLE,
                      thermal=THERMAL, iron_loss=True, sensors=SENSORS)
    assert fast.real._w is not None
    _lockstep(fast, ref, _dol(V_hat=180.0, f=50.0), 1000, truth_every=97)
    assert statuses[0] > 800 and fast.real.handed_back == 0, statuses


@pytest.mark.parametrize('update', ['single', 'double'])
@pytest.mark.parametrize('delay', [0, 1])
def test_carry_near_full_duty_and_overmodulation_with_a_delay(statuses, update, delay):
    """Duties near 1 (the dead band crossing into the next period) and beyond the hexagon."""
    inv = dict(INVERTER, update=update, delay=delay)
    T = T_S if update == 'single' else 0.5 * T_S
    fast, ref = _pair(schedule=P, load=LinearLoad(1.0, 0.001), T_s=T, inverter=inv,
                      sensors={'encoder_lines': 500, 'adc_bits': 10})
    v_max = inv['V_dc'] / math.sqrt(2.0)

    def command(k):
        ang = 2.0 * math.pi * 40.0 * k * T
        mag = v_max * (0.995 if (k // 300) % 2 == 0 else 1.3)
        return mag * math.cos(ang), mag * math.sin(ang)
    _lockstep(fast, ref, command, 1500, truth_every=113)
    carries = fast.real._carry
    assert statuses[0] > 1000, statuses
    assert fast.real._w[real_plant_kernel.N_EV] > 0 and carries is not None


def test_dead_time_alone_and_drops_alone(statuses):
    """Dead time without drops (signs and carry) and drops without dead time (no carry)."""
    for inv in (dict(INVERTER, v_on=0.0, r_on=0.0, e_sw=0.0, v_sw=None, i_sw=None),
                dict(INVERTER, deadtime=0.0), dict(INVERTER, deadtime=0.0, v_on=0.0)):
        inv = {k: v for k, v in inv.items() if v is not None}
        fast, ref = _pair(schedule=P, load=LinearLoad(1.0, 0.001), T_s=T_S, inverter=inv)
        _lockstep(fast, ref, _dol(V_hat=150.0, f=30.0), 600)
    assert statuses[0] > 1500, statuses


def test_ideal_source_with_substeps_sensors_and_noise():
    """No inverter, three sub-periods a period, the sensors and the measurement noise."""
    kw = {'schedule': P, 'load': PendulumLoad(1.0), 'T_s': T_S, 'max_substep': T_S / 3,
          'saturation': SATURATION, 'iron_loss': True, 'sensors': SENSORS,
          'current_noise_std': 0.1, 'speed_noise_std': 0.5, 'noise_seed': 7}
    fast, ref = _pair(**kw)
    _lockstep(fast, ref, _dol(), 800, truth_every=50)


def test_the_dc_link_trips_on_regeneration_in_both():
    """A fast shaft and a slow command: the DC link charges past V_trip (no chopper)."""
    inv = {'V_dc': 330.0, 'pwm_frequency': F_SW, 'deadtime': 2e-6, 'v_on': 1.0, 'C_dc': 2e-5,
           'V_trip': 360.0}
    fast, ref = _pair(schedule=P.with_values(J=1.0), load=None, T_s=T_S, inverter=inv,
                      omega0=250.0, x0=(0.3, 0.0, 0.3, 0.0, 0.0, 250.0))
    _lockstep(fast, ref, _dol(V_hat=150.0, f=30.0), 1500)
    assert fast.trip is not None and 'DC-link over-voltage' in fast.trip[1], fast.trip


def test_switching_between_the_paths_mid_run_keeps_the_state():
    """The compiled plant handed to the reference and back, its attributes read between."""
    kw = {'schedule': P, 'load': LinearLoad(1.0, 0.001), 'T_s': T_S, 'inverter': INVERTER,
          'saturation': SATURATION, 'thermal': THERMAL, 'iron_loss': True, 'sensors': SENSORS}
    fast, ref = _pair(**kw)
    command = _dol()
    for k0, on in ((0, True), (300, False), (450, True), (700, False), (720, True)):
        fast.real.use_kernel = on
        _lockstep(fast, ref, lambda k: command(k0 + k), 150 if k0 < 700 else 80,
                  truth_every=7)
        assert fast.real.temps == pytest.approx(ref.real.temps, rel=REL)
        assert fast.real._speed.hist == ref.real._speed.hist
        assert fast.real.P_inverter == pytest.approx(ref.real.P_inverter, rel=REL, abs=ABS)


def test_whole_period_kernel_applies_where_it_can():
    """A load the kernel does not know, or a varying resistance: the partial kernels step."""
    class Custom(LinearLoad):

        def torque(self, t, theta, omega):
            return 0.5

    assert PlantSimulator(P, Custom(), T_s=T_S, inverter=INVERTER).real._w is None
    sim = PlantSimulator(P, StepLoad(0.01, 0.0, 1.0), T_s=T_S, inverter=INVERTER)
    assert sim.real._w is not None


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
    kernels = ('period', 'events', 'explicit', 'step')
    before = {k: len(getattr(real_plant_kernel, k).signatures) for k in kernels}
    assert before['step'] == 1
    for kw in ({'inverter': INVERTER, 'saturation': SATURATION, 'iron_loss': True},
               {'inverter': dict(INVERTER, deadtime=0.0, v_on=0.0)}, {'iron_loss': True}):
        for whole in (True, False):
            sim = PlantSimulator(P, LinearLoad(1.0, 0.001), T_s=T_S, **kw)
            if not whole:
                sim.real._w = None              # the partial kernels, as for other loads
            for k in range(200):
                sim.step(*_dol()(k))
    assert {k: len(getattr(real_plant_kernel, k).signatures) for k in kernels} == before
