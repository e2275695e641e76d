"""
Commissioning on the ROS-free plant, shared by the study and the campaign.

Used by the commissioning study (:mod:`im_studies.commission_study`, docs/commissioning.md §6)
and the campaign's commissioning axis (:mod:`im_studies.campaign_spec`, docs/campaign.md): the
motor's ratings as the drive's limits, the identification and its errors against the truth.
"""
from __future__ import annotations

import os

from im_adapt.commissioning import Commissioning, Nameplate, simulate_commissioning
from im_common.params import load_motor_file, RATING_NAMES, shipped_motors_dir
from im_plant.plant_sim import PlantSimulator


def plate_of(motor):
    """Return the nameplate a motor file's ratings are (its nameplate fields)."""
    return Nameplate(voltage=motor.rated_voltage_rms_line, current=motor.rated_current_rms,
                     frequency=motor.rated_frequency, speed=motor.rated_speed_rpm,
                     power=motor.rated_power)


def commission_sim(motor, noise: float = 0.0, T_s: float = 1e-4, locked: bool = False,
                   seed: int = 0, blocks=None, magnetizing: bool = False):
    """
    Commission ``motor`` on the ROS-free plant (limits: its ratings).

    ``blocks``: the real plant's blocks (PlantSimulator keywords, docs/plant.md; none: ideal).
    ``magnetizing``: with the no-load test (the magnetizing curve; off for the studies of the
    standstill and speed tests, which it would only lengthen).

    Returns (Commissioning, Identified) — Identified raises NotInformative from ``result``.
    """
    plate = plate_of(motor)
    i_max, v_max = motor.rated_current, motor.rated_voltage
    plant = PlantSimulator(motor, T_s=T_s, current_trip=i_max, v_limit=v_max,
                           current_noise_std=noise, noise_seed=seed, locked_rotor=locked,
                           **(blocks or {}))
    com = Commissioning(T_s, i_max, v_max, pole_pairs=plate.pole_pairs,
                        test_speed=motor.rated_speed, locked=locked, magnetizing=magnetizing)
    simulate_commissioning(plant, com)
    return com


def with_ratings(motor):
    """
    ``motor``, with the thesis motor's ratings (its shipped file) if it has none.

    The commissioning tests need the drive's limits (docs/commissioning.md §6).
    """
    if motor.rated_current:
        return motor
    thesis = load_motor_file(os.path.join(shipped_motors_dir(), 'thesis.yaml'))
    return motor.with_values(**{x: getattr(thesis, x) for x in RATING_NAMES})


#: the commissioned parameters compared with the truth (the inverse-Γ set and J)
COMPARED = ('R_s', 'L_sigma', 'L_M', 'R_R', 'J')
#: the current noise [A] the noise settings are given for (the thesis motor's rated current)
NOISE_REFERENCE_A = 8.487


def identification_errors(motor, noise: float, seed: int = 0):
    """
    Commission ``motor`` and compare the identified parameters with it.

    Ratings as the limits, current noise ``noise`` [A] per NOISE_REFERENCE_A of rated current;
    returns (Commissioning, Identified, {name_err_pct, name_std_pct}). Raises NotInformative
    (one line) when the tests are refused.
    """
    com = commission_sim(motor, noise=noise * motor.rated_current / NOISE_REFERENCE_A, seed=seed)
    ident = com.result()
    truth = dict(motor.identifiable(), J=motor.J, b=motor.b)
    out = {}
    for n in COMPARED:
        out[n + '_err_pct'] = 100.0 * (ident.values[n] / truth[n] - 1.0)
        out[n + '_std_pct'] = 100.0 * ident.std[n] / ident.values[n]
    return com, ident, out
