"""Atomic writes: whole files with ordinary permissions, no stale temporaries."""

import os
import stat

from jaxplan.files import atomic_write_text


def test_atomic_write_permissions_and_stale_temporaries(tmp_path):
    stale = tmp_path / ".metrics.json.abc123.tmp"  # what a killed write leaves behind
    stale.write_text("{partial")
    other = tmp_path / ".sweep.csv.zzz.tmp"  # another file's temporary is not touched
    other.write_text("x")
    old = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "metrics.json", '{"ok": true}')
    finally:
        os.umask(old)
    p = tmp_path / "metrics.json"
    assert p.read_text() == '{"ok": true}'
    assert stat.S_IMODE(p.stat().st_mode) == 0o644
    assert not stale.exists() and other.exists()
    assert sorted(x.name for x in tmp_path.iterdir()) == [".sweep.csv.zzz.tmp", "metrics.json"]
