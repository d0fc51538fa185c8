"""The files generated from the parameter schema are current, and the generator does what it
says: a stale reference or launch <choice> list fails here with the command that fixes it."""
import pathlib

from seaforce_ros.core import schema
from seaforce_ros.core.params import MODES
from seaforce_ros.tools import generate


def test_generated_files_are_current():
    stale = [str(path.relative_to(generate.ROOT)) for path, text in generate.outputs().items()
             if not path.exists() or path.read_text() != text]
    assert not stale, ('stale (run: python -m seaforce_ros.tools.generate): '
                       + ', '.join(stale))


def test_the_reference_has_every_row_of_every_node():
    text = generate.parameters_markdown()
    for node in schema.NODES + (schema.BRINGUP,):
        for spec in schema.node_rows(node):
            key = ('<channel>.' if spec.per_channel else '') + spec.name
            assert f'| `{key}` |' in text, (node, key)
            assert spec.description.split(';')[0][:40].replace('|', '\\|') in text, key


def test_launch_choices_are_rewritten_from_the_schema():
    stale = ('<launch>\n  <arg name="pinch_mode" default="hold" description="x">\n'
             '    <choice value="hold"/>\n    <choice value="turbo"/>\n  </arg>\n'
             '  <arg name="other" default="a">\n    <choice value="a"/>\n  </arg>\n'
             '  <node pkg="seaforce_ros" exec="controller_node">\n'
             '    <param name="pinch.mode" value="$(var pinch_mode)" type="str"/>\n'
             '  </node>\n</launch>\n')
    fixed = generate.launch_choices(stale)
    assert 'turbo' not in fixed
    assert ''.join(f'    <choice value="{m}"/>\n' for m in MODES) in fixed
    assert '<arg name="other" default="a">\n    <choice value="a"/>\n  </arg>' in fixed
    assert generate.launch_choices(fixed) == fixed


def test_check_mode_reports_and_writes_nothing(tmp_path, capsys):
    (tmp_path / 'launch').mkdir()
    assert generate.main(['--check', '--root', str(tmp_path)]) == 1
    assert not (tmp_path / 'docs').exists()
    assert 'stale: docs/parameters.md' in capsys.readouterr().out
    assert generate.main(['--root', str(tmp_path)]) == 0
    assert generate.main(['--check', '--root', str(tmp_path)]) == 0
    assert (pathlib.Path(tmp_path) / 'docs' / 'parameters.md').read_text() == \
        generate.parameters_markdown()
