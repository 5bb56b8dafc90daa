"""The fleet manifest (CSV and YAML) and the refusal of a bad one by valve_identify_batch."""
from __future__ import annotations

from pathlib import Path

import pytest

from valve_model_pkg.cli.identify_batch import main
from valve_model_pkg.fleet import ManifestError, read_manifest


@pytest.fixture()
def records(tmp_path: Path) -> Path:
    for name in ('a/fit.csv', 'a/val.csv', 'b/fit1.csv', 'b/fit2.csv', 'b/val.csv',
                 'known.yaml'):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text('t,voltage,current\n', encoding='utf-8')
    return tmp_path


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding='utf-8')
    return path


def test_csv_manifest_resolves_paths_relative_to_itself_and_splits_on_semicolons(
        records: Path) -> None:
    m = _write(records / 'fleet.csv',
               '# a comment line\n'
               'valve_id,fit,validate,quick,params\n'
               'A1,a/fit.csv,a/val.csv,,\n'
               'B2,b/fit1.csv; b/fit2.csv,b/val.csv,yes,known.yaml\n')
    jobs = read_manifest(m, {'diagnose': False})
    assert [j.valve_id for j in jobs] == ['A1', 'B2']
    assert jobs[0].fit == (str((records / 'a/fit.csv').resolve()),)
    assert jobs[1].fit == tuple(str((records / f'b/fit{k}.csv').resolve()) for k in (1, 2))
    assert jobs[0].options == {'diagnose': False}
    assert jobs[1].options == {'quick': True, 'diagnose': False,
                               'params': str((records / 'known.yaml').resolve())}
    assert jobs[1].line == 4
    # The fingerprint follows records and options (what resume compares).
    assert jobs[0].fingerprint() != jobs[1].fingerprint()
    assert jobs[0].fingerprint() == read_manifest(m, {'diagnose': False})[0].fingerprint()
    assert jobs[0].fingerprint() != read_manifest(m)[0].fingerprint()


def test_yaml_manifest_with_defaults_and_per_valve_options(records: Path) -> None:
    m = _write(records / 'fleet.yaml',
               'defaults:\n  quick: true\n  plots: false\n'
               'valves:\n'
               '  - valve_id: A1\n    fit: a/fit.csv\n    validate: [a/val.csv]\n'
               '  - valve_id: B2\n    fit: [b/fit1.csv, b/fit2.csv]\n    quick: false\n')
    a, b = read_manifest(m)
    assert a.options == {'quick': True, 'plots': False} and len(a.validate) == 1
    assert b.options == {'quick': False, 'plots': False} and b.validate == ()
    assert len(b.fit) == 2 and a.line == 5 and b.line == 8
    # A bare list is a manifest too.
    m2 = _write(records / 'list.yml', '- {valve_id: A1, fit: a/fit.csv}\n')
    assert read_manifest(m2)[0].valve_id == 'A1'


def test_route_electronics_and_topic_map_reach_the_identification_settings(
        records: Path) -> None:
    from valve_model_pkg.fleet.worker import settings_from_options
    _write(records / 'driver.yaml', 'electronics: {}\n')
    m = _write(records / 'fleet.yaml',
               'valves:\n'
               '  - valve_id: A1\n    fit: a/fit.csv\n    route: mean-voltage\n'
               '    electronics: driver.yaml\n    fit_electronics: true\n'
               '    map: "current=/coil/current; duty=/pwm.duty"\n'
               '  - valve_id: B2\n    fit: a/fit.csv\n    choose_electronics: yes\n')
    a, b = read_manifest(m)
    assert a.options['electronics'] == str((records / 'driver.yaml').resolve())
    sa, sb = settings_from_options(a.options), settings_from_options(b.options)
    assert sa.route == 'mean-voltage' and not sa.electronics_fixed
    assert sa.electronics is not None
    assert sa.topic_map == ('current=/coil/current', 'duty=/pwm.duty')
    assert sb.choose_electronics and sb.electronics is None and sb.route == 'auto'
    # The options are part of what a resumed run compares.
    assert a.fingerprint() != read_manifest(_write(
        records / 'other.yaml', 'valves:\n  - {valve_id: A1, fit: a/fit.csv}\n'))[0].fingerprint()


@pytest.mark.parametrize('name, text, where, words', [
    ('m.yaml', 'valves: [{valve_id: A1, fit: a/fit.csv, route: sideways}]\n',
     'm.yaml:1: route:', ["'sideways'", 'mean-voltage']),
    ('m.yaml', 'valves: [{valve_id: A1, fit: a/fit.csv, electronics: none.yaml}]\n',
     'm.yaml:1: electronics:', ["'none.yaml'", 'no such file']),
    ('m.yaml', 'valves: [{valve_id: A1, fit: a/fit.csv, fit_electronics: true}]\n',
     'm.yaml:1: fit_electronics:', ['electronics file']),
    ('m.yaml', 'valves: [{valve_id: A1, fit: a/fit.csv, choose_electronics: true,\n'
     '           electronics: known.yaml}]\n', 'm.yaml:1: choose_electronics:',
     ['exclude']),
    ('m.csv', 'valve_id,fit,map\nA1,a/fit.csv,current=/c;current=/d\n', 'm.csv:2: map:',
     ['given twice']),
    ('m.csv', 'valve_id,fit\nA1,a/missing.csv\n', 'm.csv:2: fit:', ["'a/missing.csv'",
                                                                    'no such file']),
    ('m.csv', 'valve_id,fit,colour\nA1,a/fit.csv,red\n', 'm.csv:1: colour:', ['unknown']),
    ('m.csv', 'valve_id,validate\nA1,a/val.csv\n', 'm.csv:1: fit:', ['missing column']),
    ('m.csv', 'valve_id,fit\nA1,a/fit.csv\nA1,a/fit.csv\n', 'm.csv:3: valve_id:',
     ["'A1' listed twice", 'line 2']),
    ('m.csv', 'valve_id,fit\n../up,a/fit.csv\n', 'm.csv:2: valve_id:', ["'../up'"]),
    ('m.csv', 'valve_id,fit,quick\nA1,a/fit.csv,maybe\n', 'm.csv:2: quick:', ["'maybe'"]),
    ('m.csv', 'valve_id,fit\nA1,\n', 'm.csv:2: fit:', ['no fit record']),
    ('m.csv', 'valve_id,fit\nA1,a/fit.csv,extra\n', 'm.csv:2:', ['3 cells for 2 columns']),
    ('m.csv', '', 'm.csv:', ['empty manifest']),
    ('m.yaml', 'valves:\n  - valve_id: A1\n    fit: a/fit.csv\n  - valve_id: B2\n'
     '    fit: a/fit.csv\n    validate: [a/nope.csv]\n', 'm.yaml:6: validate:',
     ["'a/nope.csv'"]),
    ('m.yaml', 'valves:\n  - valve_id: A1\n    fit: a/fit.csv\n    qiuck: true\n',
     'm.yaml:4: qiuck:', ['unknown key']),
    ('m.yaml', 'defaults: {speed: 3}\nvalves: [{valve_id: A1, fit: a/fit.csv}]\n',
     'm.yaml:1: speed:', ['not a per-valve option']),
    ('m.yaml', 'valves: [\n', 'm.yaml:', ['not valid YAML']),
    ('m.yaml', 'valves: []\n', 'm.yaml:1: valves:', ['non-empty list']),
    ('m.json', '{}', 'm.json:', ["unknown manifest type '.json'"]),
])
def test_a_bad_manifest_is_refused_naming_file_line_key_and_value(
        records: Path, name: str, text: str, where: str, words: list[str]) -> None:
    m = _write(records / name, text)
    with pytest.raises(ManifestError) as info:
        read_manifest(m)
    msg = str(info.value)
    assert msg.startswith(str(m) + where[len(name):]), msg
    for w in words:
        assert w in msg, msg
    assert '\n' not in msg


def test_command_line_refuses_a_bad_manifest_with_one_line_and_exit_2(
        records: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    m = _write(records / 'fleet.csv', 'valve_id,fit\nA1,a/fit.csv\nB2,b/none.csv\n')
    out = tmp_path / 'out'
    assert main([str(m), '-o', str(out)]) == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith('valve_identify_batch: error: ')
    assert f'{m}:3: fit:' in lines[0] and "'b/none.csv'" in lines[0]
    assert not out.exists()               # nothing written for refused input
    missing = tmp_path / 'nowhere.yaml'
    assert main([str(missing), '-o', str(out)]) == 2
    assert f'{missing}: no such file' in capsys.readouterr().err
    assert not out.exists()


def test_command_line_help_names_the_output_option(capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as info:
        main(['--help'])
    assert info.value.code == 0
    text = capsys.readouterr().out
    for option in ('-o', '--out', '--workers', '--scheduler', '--resume', '--no-resume'):
        assert option in text
