"""Screenshots of a page file with Debian's headless Chromium (``/usr/bin/chromium``; the
test script installs it when missing): no sandbox, GPU, network services or profile of its
own beyond a throw-away directory."""
import os
import pathlib
import shutil
import subprocess

__all__ = ['CHROMIUM', 'screenshot']

CHROMIUM = '/usr/bin/chromium'


def screenshot(page, out, tmp, size=(1280, 6000), timeout=120):
    """Chromium's screenshot of the file ``page`` at ``size`` (w, h) px, scale 1, saved as
    ``out`` (returned); its profile lives in ``tmp`` and is removed after. Fails with Chromium's
    stderr when it did not write the file."""
    assert os.access(CHROMIUM, os.X_OK), (
        f'{CHROMIUM} is missing: scripts/test installs it (apt-get install chromium)')
    out = pathlib.Path(out)
    profile = pathlib.Path(tmp) / f'chromium-profile-{out.stem}'
    cmd = [CHROMIUM, '--headless', '--no-sandbox', '--disable-gpu', '--disable-quic',
           '--no-first-run', '--disable-background-networking', '--disable-component-update',
           '--disable-sync', f'--user-data-dir={profile}', '--force-device-scale-factor=1',
           '--hide-scrollbars', f'--screenshot={out}', f'--window-size={size[0]},{size[1]}',
           pathlib.Path(page).resolve().as_uri()]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    finally:
        shutil.rmtree(profile, ignore_errors=True)
    assert done.returncode == 0 and out.exists(), done.stderr[-2000:]
    return out
