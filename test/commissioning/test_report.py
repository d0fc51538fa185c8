"""The commissioning report: report.json round trip, escaping, a self-contained page, clear
errors with nothing half-written, and a headless Chromium screenshot that shows every figure.

How the screenshot check works: every figure PNG carries its own marker colour
(``FIGURE_MARKERS``, a colour with one channel 0 and one 255 that no plot line, band, text or
CSS of the report uses): a 30 px lettered badge in its top left corner and a 12 px square in
its bottom right corner. In the screenshot, the pixels of a figure's colour must (1) exist,
(2) fill the badge's corner and the square's corner, and (3) span exactly the PNG's width and
height. A missing image has no such pixels, a broken one shows the browser's icon instead, a
truncated or partly decoded one lacks the bottom square, a scaled or cropped one spans the
wrong size, an image shown twice spans twice its height. The second test hands the check
pages with a figure removed, truncated, not a PNG, or replaced by another, and proves it
names exactly those figures.
"""
import base64
import errno
import html.parser
import json
import math
import os
import pathlib
import re
import shutil
import tempfile

import numpy as np
import pytest
from PIL import Image

from helpers import chromium
from helpers.report_example import example_report
from seaforce_ros.commissioning import report as rp
from seaforce_ros.commissioning.errors import CommissioningError
from seaforce_ros.commissioning.report import (FIGURE_MARKERS, ReportError, load_report,
                                               report_json, summary_table, write_report)

WINDOW = (1280, 6000)   # wide enough for the 1100 px figures at 1:1, tall enough for the page
TOLERANCE = 6           # per colour channel


# --- the screenshot and its check -------------------------------------------------------------

def screenshot(page, out, tmp):
    return chromium.screenshot(page, out, tmp, size=WINDOW)


def figure_problems(shot, sizes):
    """What the screenshot lacks: one line per figure of ``sizes`` (letter -> PNG (w, h))
    whose two marks are not there, in their corners, spanning the PNG's size."""
    img = np.asarray(Image.open(shot).convert('RGB')).astype(np.int16)
    problems = []
    for letter, (w, h) in sizes.items():
        rgb = np.array(FIGURE_MARKERS[letter][1], dtype=np.int16)
        mask = np.all(np.abs(img - rgb) <= TOLERANCE, axis=2)
        ys, xs = np.nonzero(mask)
        if len(ys) == 0:
            problems.append(f'({letter}) not on the page')
            continue
        y0, y1, x0, x1 = ys.min(), ys.max(), xs.min(), xs.max()
        badge = mask[y0:y0 + 30, x0:x0 + 30].sum()
        square = mask[y1 - 11:y1 + 1, x1 - 11:x1 + 1].sum()
        span = (x1 - x0 + 1, y1 - y0 + 1)
        if badge < 500:
            problems.append(f'({letter}) badge: {badge} of 900 px')
        if square < 130:
            problems.append(f'({letter}) bottom-right square: {square} of 144 px')
        if abs(span[0] - w) > 1 or abs(span[1] - h) > 1:
            problems.append(f'({letter}) spans {span[0]}x{span[1]} px, the PNG is {w}x{h}')
    return problems


def png_sizes(directory):
    out = {}
    for letter, (name, _) in FIGURE_MARKERS.items():
        p = directory / name
        if p.exists():
            with Image.open(p) as im:
                out[letter] = im.size
    return out


@pytest.fixture(scope='module')
def written(tmp_path_factory):
    """The example report written once, with its screenshot."""
    tmp = tmp_path_factory.mktemp('report')
    data = example_report(seed=3)
    page = write_report(tmp / 'run', data)
    shot = screenshot(page, tmp / 'shot.png', tmp)
    return data, page, shot, tmp


def test_screenshot_shows_every_figure(written):
    data, page, shot, _ = written
    sizes = png_sizes(page.parent)
    assert sorted(sizes) == ['a', 'b', 'c', 'd', 'e']
    assert figure_problems(shot, sizes) == []
    # The colours are the figures' own: the page's text and CSS never use them.
    text = re.sub(r'data:image/png;base64,[A-Za-z0-9+/=]+', '', page.read_text()).lower()
    for _, rgb in FIGURE_MARKERS.values():
        assert '#%02x%02x%02x' % rgb not in text
        assert 'rgb(%d, %d, %d)' % rgb not in text and 'rgb(%d,%d,%d)' % rgb not in text


def _img_tags(text):
    return list(re.finditer(r'<img src="data:image/png;base64,([A-Za-z0-9+/=]+)"', text))


def test_check_catches_a_missing_or_broken_figure(written):
    """Two tampered pages (the check reads each colour on its own, so one page can carry
    two faults; the untouched figures prove it flags nothing else)."""
    _, page, _, tmp = written
    text = page.read_text()
    sizes = png_sizes(page.parent)
    tags = _img_tags(text)
    assert len(tags) == 5
    a, b, c, d, _ = (t.group(1) for t in tags)
    half = b[:len(b) // 2]
    # 1: (c)'s whole <figure> removed; (b) cut in the middle of its data (the browser
    #    decodes its top rows only)
    one = re.sub(r'<figure id="fig-c">.*?</figure>', '', text, flags=re.S)
    one = one.replace(b, half[:len(half) // 4 * 4])
    # 2: (a) not a PNG at all (the broken-image icon); (d) replaced by (c): (d)'s colour is
    #    gone, (c)'s spans two images
    two = text.replace(a, base64.b64encode(b'not a png').decode()).replace(d, c)
    for name, variant, expected in (('one', one, {'b', 'c'}), ('two', two, {'a', 'c', 'd'})):
        tampered = page.parent / f'tampered-{name}.html'
        tampered.write_text(variant)
        problems = figure_problems(screenshot(tampered, tmp / f'shot-{name}.png', tmp), sizes)
        assert {p[1] for p in problems} == expected, (name, problems)
        tampered.unlink()


def test_partial_report_draws_what_it_has(tmp_path):
    """A run that stopped before the noise sweep and the tuning: figures (a)-(c), the page
    says (d) and (e) were not drawn, the screenshot shows the three."""
    data = example_report(seed=1)
    data.noise, data.tuning, data.zwidth.wall, data.work_loops = None, None, None, []
    page = write_report(tmp_path / 'partial', data)
    sizes = png_sizes(page.parent)
    assert sorted(sizes) == ['a', 'b', 'c']
    assert 'torque_noise.png: not drawn' in page.read_text()
    assert 'work_loops.png: not drawn' in page.read_text()
    assert figure_problems(screenshot(page, tmp_path / 'shot.png', tmp_path), sizes) == []


# --- report.json ------------------------------------------------------------------------------

@pytest.fixture(scope='module')
def drawn_once():
    return rp.render_figures(example_report())


@pytest.fixture
def fast_figures(monkeypatch, drawn_once):
    """write_report with the example's figures drawn once: for the tests about the files and
    the page's text, not the figures."""
    monkeypatch.setattr(rp, 'render_figures', lambda data: drawn_once)


def test_json_round_trip(tmp_path, fast_figures):
    data = example_report(seed=2)
    data.zwidth.wall.k_quantisation[:5] = np.inf   # no quantisation limit at low damping
    data.meta.seed = None
    page = write_report(tmp_path / 'r', data)
    raw = json.loads((page.parent / 'report.json').read_text())
    assert raw['schema'] == rp.SCHEMA
    m_e = raw['identification'][5]
    assert m_e['value'] is None and m_e['sigma'] is None and m_e['status'].startswith('not ')
    wall = raw['zwidth']['wall']
    assert wall['k_quantisation'][:5] == ['inf'] * 5
    assert wall['binding'][0] == 'passivity' and wall['binding'][-1] == 'quantisation'
    assert wall['k_max'][-1] == 600.0 and wall['k_max'][0] == wall['k_passivity'][0]
    assert raw['meta']['seed'] is None
    for key in ('sigma', 'coherence'):
        assert len(raw['responses'][0][key]) == len(raw['responses'][0]['omega'])
    back = load_report(page.parent)
    assert report_json(back) == report_json(data)
    assert isinstance(back.responses[0].measured, np.ndarray)
    np.testing.assert_array_equal(back.responses[1].measured, data.responses[1].measured)
    np.testing.assert_array_equal(back.impedance[3].z, data.impedance[3].z)
    assert math.isnan(back.identification[5].value)
    assert back.identification[4].previous == data.identification[4].previous
    assert back.zwidth.wall.binding == data.zwidth.wall.binding
    assert back.meta.phases == data.meta.phases and back.meta.dry_run
    assert summary_table(back) == summary_table(data)


def test_load_report_refuses_other_schemas_and_garbage(tmp_path, fast_figures):
    page = write_report(tmp_path / 'r', example_report())
    path = page.parent / 'report.json'
    raw = json.loads(path.read_text())
    raw['schema'] = rp.SCHEMA + 1
    path.write_text(json.dumps(raw))
    with pytest.raises(ReportError, match='schema'):
        load_report(path)
    raw['schema'] = rp.SCHEMA
    raw['responses'][0]['omega'] = 'fast'
    path.write_text(json.dumps(raw))
    with pytest.raises(ReportError, match=r'responses\[0\]\.omega'):
        load_report(path)
    path.write_text('{not json')
    with pytest.raises(ReportError, match='not JSON'):
        load_report(path)
    with pytest.raises(ReportError, match='cannot read'):
        load_report(tmp_path / 'nowhere')


def test_degenerate_data_still_writes_a_report(tmp_path, recwarn):
    """NaN, zero and inf where numbers belong, empty arrays and tables: every file is
    written, no warning escapes, the text says what is missing."""
    d = example_report()
    for r in d.responses:
        r.measured[:], r.model[:], r.sigma[:], r.coherence[:] = np.nan, 0, np.nan, np.nan
    for m in d.impedance:
        m.z[:], m.lower[:], m.upper[:] = np.nan, 0, np.inf
    d.zwidth.predicted_db[:] = np.nan
    d.zwidth.wall.k_passivity[:], d.zwidth.wall.k_quantisation[:] = np.nan, np.inf
    d.noise.rms[:], d.noise.budget, d.noise.chosen = 0, np.nan, np.nan
    d.identification[0].value = np.inf
    d.work_loops[0].f_e[:] = np.nan
    page = write_report(tmp_path / 'nan', d)
    assert sorted(png_sizes(page.parent)) == ['a', 'b', 'c', 'd', 'e']
    assert report_json(load_report(page.parent)) == report_json(d)
    assert 'no finite prediction' in page.read_text()
    empty = rp.CommissioningReport(
        meta=rp.ReportMeta('x', 'now', {}, applied=True),
        responses=[rp.PortResponse('F_p/X', '', [], [], [], [], [])],
        impedance=[rp.ModeImpedance('dob', [], [], [], [])],
        zwidth=rp.ZWidthChart([], [], [], [], wall=rp.WallBoundary([], [], [])),
        noise=rp.NoiseSweep([], [], [], 1, 1), tuning=rp.Tuning([], ''))
    page = write_report(tmp_path / 'empty', empty)
    assert sorted(png_sizes(page.parent)) == ['a', 'b', 'c', 'd']
    text = summary_table(empty)
    assert 'phases: -' in text and 'binding constraint: -' in text
    assert 'no finite prediction' in text and 'no chosen damping' in text
    assert [str(w.message) for w in recwarn] == []


def test_data_changed_after_construction_is_checked_again(tmp_path, fast_figures):
    d = example_report()
    d.responses[0].coherence = d.responses[0].coherence[:-1]
    with pytest.raises(ReportError, match=r'nothing written: .*coherence has'):
        write_report(tmp_path / 'r', d)
    assert not (tmp_path / 'r').exists()


def test_wall_boundary_names_the_limit_that_binds():
    """K_max(B) = min(2 B / T + 2, 600) with T = 1.5 ms: passivity binds below
    B = 0.447 N m s/rad, quantisation above (the example's curves)."""
    wall = example_report().zwidth.wall
    assert wall.binding[0] == 'passivity' and wall.binding[-1] == 'quantisation'
    k, which = wall.at_chosen()
    assert which == 'passivity' and k == pytest.approx(2 * 0.3 / 1.5e-3 + 2, rel=1e-9)
    wall.chosen_damping = 0.5
    assert wall.at_chosen() == (600.0, 'quantisation')
    assert 'K_max = 600 N m/rad (quantisation binds), chosen K = 300' in wall.describe()
    np.testing.assert_array_equal(wall.k_max, np.minimum(wall.k_passivity, 600.0))


def test_drift_against_the_last_commissioning():
    row = rp.ParameterRow('plant.hose_stiffness', 'k_s', 'N m/rad', 13.02, 0.21, previous=12.1)
    assert row.drift_sigmas == pytest.approx((13.02 - 12.1) / 0.21)
    assert rp._drift(row) == '12.1 (+7.6 %, +4.4 sigma)'
    row.sigma = np.nan
    assert rp._drift(row) == '12.1 (+7.6 %)'
    row.previous = 0.0
    assert rp._drift(row) == '0'
    row.previous = np.nan
    assert rp._drift(row) == '-' and math.isnan(row.drift_sigmas)


def test_bad_data_is_refused_with_the_field_named():
    with pytest.raises(ReportError, match='sigma has 3 values'):
        rp.PortResponse('F_p/X', 'N m/rad', [1, 2], [1, 2], [1, 2, 3], [1, 1], [1, 2])
    with pytest.raises(ReportError, match='omega must be finite and > 0'):
        rp.ModeImpedance('dob', [0.0, 1.0], [1, 1], [1, 1], [1, 1])
    with pytest.raises(ReportError, match='coherence must be a list of numbers'):
        rp.PortResponse('F_p/X', 'N m/rad', [1, 2], [1, 2], [1, 2], ['a', 'b'], [1, 2])
    with pytest.raises(ReportError, match='lower must be a list of numbers .*complex'):
        rp.ModeImpedance('dob', [1.0], [1j], [1j], [1])
    with pytest.raises(ReportError, match=r'upper must be one-dimensional, .*\(1, 2\)'):
        rp.ModeImpedance('dob', [1.0, 2.0], [1, 1], [1, 1], [[1, 1]])
    with pytest.raises(ReportError, match="plant.k_s: sigma must be a number, got 'small'"):
        rp.ParameterRow('plant.k_s', 'k_s', 'N m/rad', 13.0, 'small')
    with pytest.raises(ReportError, match='phases must map'):
        rp.ReportMeta('x', 'now', {'identification': 'long'}, applied=False)
    assert issubclass(ReportError, CommissioningError)


# --- the page: escaping, nothing external -----------------------------------------------------

class _Tags(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.tags, self.attrs = [], []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        self.attrs += [(tag, k, v or '') for k, v in attrs]


def test_html_escapes_every_text(tmp_path, fast_figures):
    evil = '<script>alert("x")</script>&<b>'
    data = example_report()
    data.meta.channel = evil
    data.identification[5].status = f'not identified ({evil})'
    data.tuning.rows[0].bound_by = evil
    data.summary.append(evil)
    data.meta.phases[evil] = 1.0
    page = write_report(tmp_path / 'r', data)
    text = page.read_text()
    parser = _Tags()
    parser.feed(text)
    assert 'script' not in parser.tags and 'b' in parser.tags   # the page's own <b> only
    assert '<script>' not in text
    assert text.count('&lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt;&amp;&lt;b&gt;') >= 6
    assert summary_table(data).count(evil) >= 3   # plain text stays as it is


def test_html_references_nothing_external(written):
    _, page, _, _ = written
    text = page.read_text()
    parser = _Tags()
    parser.feed(text)
    outside = re.sub(r'data:image/png;base64,[A-Za-z0-9+/=]+', '', text)
    assert not re.search(r'https?:|ftp:|file:|//[a-z]', outside, re.I)
    assert not {'script', 'link', 'iframe', 'object', 'embed', 'base'} & set(parser.tags)
    assert 'url(' not in text and '@import' not in text
    srcs = [v for tag, k, v in parser.attrs if k in ('src', 'href', 'srcset', 'data')]
    assert len(srcs) == 5
    assert all(v.startswith('data:image/png;base64,') for v in srcs)
    for v in srcs:   # each is a whole PNG
        assert base64.b64decode(v.split(',', 1)[1]).startswith(b'\x89PNG\r\n\x1a\n')


# --- errors: nothing half-written -------------------------------------------------------------

def test_directory_that_is_a_file(tmp_path, fast_figures):
    f = tmp_path / 'taken'
    f.write_text('x')
    with pytest.raises(ReportError, match='it is a file'):
        write_report(f, example_report())
    with pytest.raises(ReportError, match='a part of the path is a file'):
        write_report(f / 'sub', example_report())
    assert f.read_text() == 'x'


def _in_child_as_nobody(fn):
    """Run ``fn`` in a forked child with uid/gid nobody (root writes anywhere); its error
    message, or 'no error'."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:   # the child: never returns into pytest
        code = 0
        try:
            os.close(r)
            os.setgid(65534)
            os.setuid(65534)
            try:
                fn()
                msg = 'no error'
            except ReportError as exc:
                msg = f'ReportError: {exc}'
            except BaseException as exc:  # noqa: B902 - reported to the parent as text
                msg = f'{type(exc).__name__}: {exc}'
            os.write(w, msg.encode())
        except BaseException:  # noqa: B902
            code = 1
        finally:
            os._exit(code)
    os.close(w)
    with os.fdopen(r) as fh:
        msg = fh.read()
    _, status = os.waitpid(pid, 0)
    assert status == 0, msg
    return msg


def test_unwritable_directory(fast_figures):
    base = pathlib.Path(tempfile.mkdtemp(prefix='report-ro-'))
    try:
        base.chmod(0o755)
        locked = base / 'locked'
        locked.mkdir(mode=0o555)
        locked.chmod(0o555)
        data = example_report()
        for target in (locked, locked / 'new' / 'run'):
            def attempt():
                write_report(target, data)
            if os.geteuid() == 0:
                msg = _in_child_as_nobody(attempt)
            else:
                with pytest.raises(ReportError) as err:
                    attempt()
                msg = f'ReportError: {err.value}'
            assert msg.startswith('ReportError: ') and 'permission' in msg, msg
            assert str(locked) in msg
        assert list(locked.iterdir()) == []
    finally:
        locked.chmod(0o755)
        shutil.rmtree(base)


@pytest.mark.parametrize('fail_at', [1, 4, 6])
def test_disk_full_leaves_nothing_half_written(tmp_path, monkeypatch, fail_at, fast_figures):
    """The disk fills while the n-th file is written: a ReportError that says so, no temporary
    file, an earlier report in the directory as it was, a new directory removed."""
    old = write_report(tmp_path / 'again', example_report(seed=5))
    before = {p.name: p.read_bytes() for p in old.parent.iterdir()}
    calls = []
    real_fsync = os.fsync

    def fsync(fd):
        calls.append(fd)
        if len(calls) == fail_at:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_fsync(fd)
    monkeypatch.setattr(rp.os, 'fsync', fsync)
    for target in (old.parent, tmp_path / 'fresh' / 'run'):
        calls.clear()
        with pytest.raises(ReportError, match='the disk is full: free some space'):
            write_report(target, example_report(seed=6))
    assert {p.name: p.read_bytes() for p in old.parent.iterdir()} == before
    assert not (tmp_path / 'fresh').exists()


def test_failed_rename_leaves_no_page(tmp_path, monkeypatch, fast_figures):
    """A rename that fails after others succeeded: no report.html (the run does not look
    complete), no temporary file."""
    old = write_report(tmp_path / 'r', example_report())
    calls = []
    real_replace = os.replace

    def replace(src, dst):
        calls.append(dst)
        if len(calls) == 3:
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        real_replace(src, dst)
    monkeypatch.setattr(rp.os, 'replace', replace)
    with pytest.raises(ReportError, match='Input/output error: give another directory'):
        write_report(old.parent, example_report(seed=4))
    names = sorted(p.name for p in old.parent.iterdir())
    assert 'report.html' not in names and not [n for n in names if n.endswith('.tmp')]
