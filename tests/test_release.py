"""Release basics: `morphmimic --version`, the LICENSE pyproject.toml names, CITATION.cff, the
changelog, one set of version floors in pyproject.toml and the README, and README examples that
write only under ignored folders."""

from __future__ import annotations

import hashlib
import re
import shlex
import subprocess
import sys
import tomllib
from importlib import metadata
from pathlib import Path

import pytest
import yaml
from packaging.requirements import Requirement

import common.version
from learner.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[1]
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
README = (ROOT / "README.md").read_text()
APACHE_2_SHA256 = "cfc7749b96f63bd31c3c42b5c471bf756814053e847c10f3eb003417bc523d30"
"""sha256 of the Apache License 2.0 as the ASF publishes it (LICENSE-2.0.txt)."""


def requirement(name: str) -> Requirement:
    return next(r for r in map(Requirement, PROJECT["dependencies"]) if r.name == name)


def test_version_option_prints_the_version(capsys: pytest.CaptureFixture[str]) -> None:
    for flag in ("--version", "-V"):
        assert cli_main([flag]) == 0
        assert capsys.readouterr().out == f"morphmimic {common.version.version()}\n"
    out = subprocess.run([sys.executable, "-m", "learner.cli", "--version"], cwd=ROOT, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0 and re.fullmatch(r"morphmimic \d+\.\d+\.\d+\S*\n", out.stdout), out


def test_version_from_metadata_else_pyproject(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(metadata, "version", lambda name: "9.8.7" if name == "morphmimic" else "")
    assert common.version.version() == "9.8.7"

    def not_installed(name: str) -> str:
        raise metadata.PackageNotFoundError(name)

    monkeypatch.setattr(metadata, "version", not_installed)
    assert common.version.version() == PROJECT["version"]
    monkeypatch.setattr(common.version, "PYPROJECT", ROOT / "no-such-pyproject.toml")
    assert common.version.version() == "unknown"


def test_license_is_the_apache_2_text_pyproject_names() -> None:
    assert PROJECT["license"] == {"text": "Apache-2.0"}
    text = (ROOT / "LICENSE").read_bytes()
    assert hashlib.sha256(text).hexdigest() == APACHE_2_SHA256, "LICENSE is the unmodified Apache License 2.0"
    assert "Apache-2.0" in README


def test_citation_cites_the_project_and_both_papers() -> None:
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert cff["version"] == PROJECT["version"] and cff["license"] == PROJECT["license"]["text"]
    papers = {ref["title"]: ref for ref in cff["references"]}
    won = papers["Learning Body Shape Variation in Physics-based Characters"]
    assert [a["family-names"] for a in won["authors"]] == ["Won", "Lee"]
    assert (won["journal"], won["volume"], won["issue"], won["year"]) == ("ACM Transactions on Graphics", 38, "6", 2019)
    unicon = papers["UniCon: Universal Neural Controller For Physics-based Character Motion"]
    assert [a["family-names"] for a in unicon["authors"]] == ["Wang", "Guo", "Shugrina", "Fidler"]
    assert unicon["year"] == 2020 and "arXiv:2011.15119" in {i["value"] for i in unicon["identifiers"]}


def test_changelog_has_unreleased_and_this_version() -> None:
    headings = re.findall(r"^## \[([^\]]+)\]", (ROOT / "CHANGELOG.md").read_text(), re.M)
    assert headings[0] == "Unreleased"
    assert PROJECT["version"] in headings


def test_one_set_of_version_floors() -> None:
    """pyproject.toml and the README state the same floors and bounds."""
    python = re.fullmatch(r">=(\d+\.\d+)", PROJECT["requires-python"]).group(1)
    mujoco = re.fullmatch(r">=(\d+\.\d+)", str(requirement("mujoco").specifier)).group(1)
    said = " ".join(README.split())
    assert f"needs Python {python}+ and MuJoCo {mujoco}+" in said
    torch_in_readme = {str(Requirement(r).specifier) for r in re.findall(r'"(torch[<>=!,.\d]+)"', said)}
    assert torch_in_readme == {str(requirement("torch").specifier)}
    upper = next(spec.version for spec in requirement("torch").specifier if spec.operator == "<")
    assert f"`torch` is bounded below {upper}" in said


OUTPUT_FLAGS = ("--out", "--mjcf", "--png")


def readme_outputs() -> list[tuple[str, str]]:
    """`(command, path)` for every file or folder a README example names with an output flag."""
    found = []
    for block in re.findall(r"\n\n((?:    .*\n)+)", README):
        for line in re.sub(r"\\\n\s*", " ", block).splitlines():
            command = line.split("#")[0].strip()
            if not (command.startswith("morphmimic") or command.startswith("python -m")):
                continue
            words = shlex.split(command)
            found += [(command, words[i + 1]) for i, word in enumerate(words[:-1]) if word in OUTPUT_FLAGS]
    return found


def test_readme_examples_write_under_ignored_folders() -> None:
    outputs = readme_outputs()
    assert len(outputs) >= 10, outputs  # the examples were found
    if subprocess.run(["git", "rev-parse"], cwd=ROOT, capture_output=True).returncode != 0:
        pytest.skip("not a git checkout")
    tracked = [path for _, path in outputs
               if subprocess.run(["git", "check-ignore", "-q", path], cwd=ROOT).returncode != 0]
    assert not tracked, f"README examples write where git would track the output: {tracked}"


def test_character_writes_into_folders_it_makes(tmp_path: Path) -> None:
    """`--mjcf runs/characters/biped.xml` on a fresh clone, where runs/ does not exist yet."""
    out = tmp_path / "runs" / "characters" / "lower_biped.xml"
    assert cli_main(["character", "lower_biped", "--mjcf", str(out)]) == 0
    assert out.read_text().lstrip().startswith("<mujoco")
