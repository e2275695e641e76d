"""The design_gains executable's CLI: writes only certified gains, in the documented YAML."""
import json
import re

import pytest

from im_controller import design_gains


def _floats(text, key):
    m = re.search(rf'{key}: \[([^\]]*)\]', text)
    assert m, f'{key} missing'
    return [float(x) for x in m.group(1).split(',')]


def test_writes_parameters_yaml_with_certificate(tmp_path):
    out = tmp_path / 'gains.yaml'
    rc = design_gains.main(['--period', '1e-3', '--omega-max', '0', '--out', str(out)])
    assert rc == 0
    text = out.read_text()
    assert 'controller:\n  ros__parameters:' in text and 'observer:\n  ros__parameters:' in text
    assert len(_floats(text, 'current_gain')) == 4
    assert len(_floats(text, 'injection_gain')) == 8
    assert re.search(r'gain_period: 0\.001', text)
    cert = json.loads(out.with_suffix('.json').read_text())
    assert cert['current']['certified'] and cert['observer']['certified']
    assert cert['current']['dense_spectral_radius'] < 1


def test_no_yaml_without_certificate(tmp_path):
    out = tmp_path / 'gains.yaml'
    rc = design_gains.main(['--period', '1e-3', '--omega-max', '200', '--out', str(out)])
    assert rc == 1
    assert not out.exists()
    cert = json.loads(out.with_suffix('.json').read_text())
    assert cert['current']['status'] == 'infeasible' and cert['current']['gain'] is None


@pytest.mark.parametrize('args', [['--period', '0'], ['--period', 'nan'], ['--omega-max', '-1']])
def test_bad_arguments_are_rejected(args, capsys):
    with pytest.raises(SystemExit) as exc:
        design_gains.main(args)
    assert exc.value.code == 2
    assert args[0] in capsys.readouterr().err
