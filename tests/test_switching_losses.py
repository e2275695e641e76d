"""
The inverter's switching losses (im_common.inverter, docs/plant.md §1): closed form and books.

Each hard-switched edge of a leg dissipates ½ e_sw (V_dc/v_sw)(|i_x|/i_sw); a leg carrying a
constant current i at a duty strictly between 0 and 1 switches on and off once a carrier period,
so it loses f_sw e_sw (V_dc/v_sw)(|i|/i_sw), dead time or not, single or double update.
"""
import math

from im_common.inverter import Inverter, phase_values
from im_common.loads import LinearLoad
from im_common.metrics import energy_summary
from im_common.params import clarke, InvalidParameter, THESIS_MOTOR
from im_plant.plant_sim import PlantSimulator
import numpy as np
import pytest

P = THESIS_MOTOR
F_SW = 1e4
V_DC = 400.0
SWITCHING = {'e_sw': 2.0e-4, 'v_sw': 300.0, 'i_sw': 10.0}


def _dc_state(i):
    """Return the DC steady state at standstill carrying the complex stator current i."""
    return (P.L_s * i.real, P.L_s * i.imag, P.L_sr * i.real, P.L_sr * i.imag, 0.0, 0.0)


@pytest.mark.parametrize('update, deadtime', [('single', 0.0), ('single', 2e-6),
                                              ('double', 2e-6)])
def test_a_constant_current_leg_loses_fsw_esw_scaled(update, deadtime):
    """
    Locked rotor, a DC current held by its command: P_sw = f_sw e_sw (V/v_sw) Σ|i_x|/i_sw.

    The current's ripple within a period (the edges see it, the closed form takes the mean)
    is ~1e-3 of the current here: the books agree to that, and the switching energy the truth
    adds up equals P_switching × time.
    """
    T_s = 1.0 / F_SW if update == 'single' else 0.5 / F_SW
    for ang in (0.2, 1.3, 2.9):
        i = 12.0 * np.exp(1j * ang)
        ph = phase_values(i.real, i.imag)
        # the command that keeps i (R_s i, plus the dead time's mean error undone)
        e = deadtime * F_SW * V_DC
        err = clarke(*(-math.copysign(e, x) for x in ph))
        cmd = (P.R_s * i.real - err[0], P.R_s * i.imag - err[1])
        inv = dict(SWITCHING, V_dc=V_DC, pwm_frequency=F_SW, deadtime=deadtime, update=update)
        sim = PlantSimulator(P, None, T_s=T_s, locked_rotor=True, x0=_dc_state(i), inverter=inv)
        n = 40
        for _ in range(n):
            sim.step(*cmd)
        tr = sim.truth()
        want = F_SW * SWITCHING['e_sw'] * (V_DC / SWITCHING['v_sw']) * sum(
            abs(x) for x in ph) / SWITCHING['i_sw']
        assert tr['E_switching'] / (n * T_s) == pytest.approx(want, rel=2e-3)
        assert tr['P_switching'] == pytest.approx(want, rel=2e-3 if update == 'single' else 0.5)
        # and nothing of it without e_sw: the same run's inverter losses less exactly that
        plain = PlantSimulator(P, None, T_s=T_s, locked_rotor=True, x0=_dc_state(i),
                               inverter={k: v for k, v in inv.items() if k not in SWITCHING})
        for _ in range(n):
            plain.step(*cmd)
        assert plain.truth()['E_switching'] == 0.0
        extra = tr['E_inv'] - plain.truth()['E_inv']
        assert extra == pytest.approx(tr['E_switching'], rel=1e-12)


@pytest.mark.parametrize('reference', [None, 4])
def test_a_pulse_narrower_than_the_dead_time_switches_nothing(reference):
    """
    Pulses within the dead time make no edge, and nothing is switched once they vanish.

    The current along +α (i_a > 0, i_b = i_c < 0), the command at 99.9 % of the hexagon's vertex
    along −α: leg a's duty 0.0005 (a 0.05 µs pulse, within the 5 µs dead time: i_a > 0 keeps
    its lower diode on), legs b and c at 0.9995 (their lower devices' 0.05 µs pulses vanish too:
    each leg's lower device waits t_d after the turn-off, past the next period's turn-on). After
    the first period, whose start has no past, no leg switches: the plant applies the vertex
    exactly, V_dc·clarke(0, 1, 1), and books no switching energy. (The current falls ~6 A a
    period against that voltage: it starts at 60 A and keeps its signs over the 5 periods.)
    """
    i = complex(60.0, 0.0)
    inv = dict(SWITCHING, V_dc=V_DC, pwm_frequency=F_SW, deadtime=5e-6)
    sim = PlantSimulator(P, None, T_s=1.0 / F_SW, locked_rotor=True, x0=_dc_state(i),
                         inverter=inv)
    if reference:
        sim.real.use_reference(reference)
    v = -0.999 * V_DC * math.sqrt(2.0 / 3.0)
    sim.step(v, 0.0)
    first = sim.truth()['E_switching']
    assert first > 0.0                          # legs b and c turned on in the first period
    for _ in range(4):
        sim.step(v, 0.0)
    tr = sim.truth()
    assert phase_values(tr['i_alpha'], tr['i_beta'])[0] > 0.0
    assert tr['E_switching'] == first
    want = clarke(0.0, V_DC, V_DC)
    assert sim.v_applied == pytest.approx(want, abs=1e-9 * V_DC)


def test_switching_losses_close_the_dc_books_and_agree_with_the_reference():
    """A direct-on-line start: the exact step and fine-step RK4 book the same switching energy."""
    m = P.with_values(rated_voltage_rms_line=220.0)
    inv = dict(SWITCHING, V_dc=330.0, pwm_frequency=F_SW, deadtime=2e-6, v_on=1.0, r_on=0.03,
               C_dc=1e-3, V_chopper=380.0, R_chopper=30.0)
    out = []
    for ref in (None, 4):
        sim = PlantSimulator(m, LinearLoad(1.0, 0.001), T_s=1.0 / F_SW, inverter=inv)
        if ref:
            sim.real.use_reference(ref)
        for k in range(1500):
            v = 200.0 * np.exp(1j * 2.0 * math.pi * 60.0 * k / F_SW)
            sim.step(float(v.real), float(v.imag))
            if k % 100 == 99:
                tr = sim.truth()
                assert abs(tr['balance_residual_dc']) <= 1e-9 * tr['E_in'] + 1e-9
        out.append(sim.truth())
    exact, ref = out
    assert exact['E_switching'] > 0.05 * exact['E_inv'] > 0.0
    assert exact['E_switching'] == pytest.approx(ref['E_switching'], rel=1e-4)
    s = energy_summary(exact)
    assert s['E_switching_J'] == exact['E_switching']
    assert s['E_dc_J'] == pytest.approx(exact['E_source'] - exact['E_chopper']
                                        - exact['dW_cap'], rel=1e-9)


@pytest.mark.parametrize('spec, key', [
    ({'e_sw': 2e-4, 'v_sw': 300.0}, 'inverter.i_sw'),
    ({'e_sw': 2e-4, 'i_sw': 10.0}, 'inverter.v_sw'),
    ({'v_sw': 300.0, 'i_sw': 10.0}, 'inverter.v_sw'),
    ({'e_sw': -1e-4, 'v_sw': 300.0, 'i_sw': 10.0}, 'inverter.e_sw'),
    ({'e_sw': 2e-4, 'v_sw': 0.0, 'i_sw': 10.0}, 'inverter.v_sw'),
])
def test_a_bad_switching_block_is_one_line_naming_the_key(spec, key):
    with pytest.raises(InvalidParameter) as exc:
        Inverter.from_block(dict(spec, V_dc=V_DC, pwm_frequency=F_SW))
    text = str(exc.value)
    assert f"'{key}'" in text and '\n' not in text, text


def test_the_block_without_switching_losses_describes_itself_as_before():
    inv = Inverter.from_block({'V_dc': V_DC, 'pwm_frequency': F_SW})
    assert 'e_sw' not in inv.describe() and inv.switching_coefficient == 0.0
    inv = Inverter.from_block(dict(SWITCHING, V_dc=V_DC, pwm_frequency=F_SW))
    assert inv.describe()['e_sw'] == 2e-4
    assert inv.switching_coefficient == pytest.approx(2e-4 / 3000.0)
