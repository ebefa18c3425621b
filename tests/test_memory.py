"""glibc's mmap threshold is fixed at start, so that freed large arrays go back."""

import platform
import sys

import pytest

from follow import cli, memory


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc",
    reason="mallopt is glibc's",
)
def test_the_threshold_is_fixed_on_glibc():
    assert memory.fix_mmap_threshold() is True


def test_elsewhere_nothing_is_done(monkeypatch):
    monkeypatch.setattr(memory.sys, "platform", "darwin")
    assert memory.fix_mmap_threshold() is False


def test_every_command_fixes_it_before_it_runs(monkeypatch, capsys):
    calls = []
    monkeypatch.setattr(memory, "fix_mmap_threshold", lambda: calls.append(1) or True)
    assert cli.main(["models", "list"]) == 0
    assert calls == [1]
