"""The project's cache folders: where they are, and the size bound that empties one."""

from __future__ import annotations

from wosac_eval.runtime.cache_dirs import bounded, user_cache_dir


def test_the_cache_folder_follows_xdg(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert user_cache_dir("jax-compiled") == tmp_path / "wosac-eval" / "jax-compiled"
    monkeypatch.setenv("XDG_CACHE_HOME", "")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert user_cache_dir() == tmp_path / "home" / ".cache" / "wosac-eval"


def test_a_folder_over_its_bound_is_emptied_and_one_within_is_kept(tmp_path):
    folder = tmp_path / "compiled"
    folder.mkdir()
    for name in ("a-cache", "b-cache", "b-atime"):
        (folder / name).write_bytes(b"x" * 100)
    assert not bounded(folder, 300)
    assert len(list(folder.iterdir())) == 3
    assert bounded(folder, 299)
    assert list(folder.iterdir()) == []
    assert not bounded(tmp_path / "absent", 0)
