"""Fixtures the installed-product tests share."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.installed.test_installed_product import _TREE_IGNORE, REPO, build_wheel


@pytest.fixture(scope="session")
def tree_wheel(tmp_path_factory) -> Path:
    """The wheel of a copy of the whole checkout (pip builds in the source folder), built
    once for every installed test."""
    tmp = tmp_path_factory.mktemp("tree")
    shutil.copytree(REPO, tmp / "src", ignore=_TREE_IGNORE)
    return build_wheel(tmp / "src", tmp / "dist")
