"""The documentation cannot drift: docs/parameters.md against pointrig.config, the size limits
of README.md and docs/, no work-log wording or scratch paths, and links into docs/ resolve."""

from __future__ import annotations

import ast
import dataclasses
import re
from pathlib import Path
from typing import Any

import pytest

from pointrig import config

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
PARAMETERS = DOCS / "parameters.md"

#: stage heading in docs/parameters.md -> its dataclass
STAGES = {
    "preprocess": config.PreprocessConfig,
    "registration": config.RegistrationConfig,
    "structure": config.StructureConfig,
    "joints": config.JointsConfig,
    "rig": config.RigConfig,
}

_HEADING = re.compile(r"^## \[(\w+)\]\s*$")
_ROW = re.compile(r"^\|\s*`(\w+)`\s*\|[^|]*\|\s*`([^`]*)`\s*\|")


def parse_parameter_tables(text: str) -> dict[str, dict[str, str]]:
    """``{stage: {field: default as written}}`` from the page's ``## [stage]`` sections: every
    table row whose first cell is a backticked name, the default being the third cell's
    backticked text.

    Raises
    ------
    ValueError
        On a field listed twice in one stage, or a row before any stage heading.
    """
    tables: dict[str, dict[str, str]] = {}
    stage = None
    for n, line in enumerate(text.splitlines(), 1):
        if m := _HEADING.match(line):
            stage = m.group(1)
            tables.setdefault(stage, {})
        elif m := _ROW.match(line):
            if stage is None:
                raise ValueError(f"line {n}: parameter row before any '## [stage]' heading")
            name, default = m.groups()
            if name in tables[stage]:
                raise ValueError(f"line {n}: [{stage}] {name} listed twice")
            tables[stage][name] = default
    return tables


def parse_default(text: str) -> Any:
    """A default as the page writes it (TOML-like: ``true``, ``"fit"``, ``[0.0, 0.0, 0.0]``,
    ``1e5``; ``None`` for unset) as the Python value."""
    words = {"true": True, "false": False, "None": None}
    if text in words:
        return words[text]
    value = ast.literal_eval(text)
    return tuple(value) if isinstance(value, list) else value


def same_value(written: Any, default: Any) -> bool:
    """Equal and of the same kind (an int is not written as ``2.0``, nor a float as ``2``)."""
    if isinstance(default, tuple):
        return (isinstance(written, tuple) and len(written) == len(default)
                and all(same_value(w, d) for w, d in zip(written, default)))
    return type(written) is type(default) and written == default


def doc_files() -> list[Path]:
    """README.md and every Markdown page under docs/."""
    return [README, *sorted(DOCS.rglob("*.md"))]


def test_parameter_tables_match_the_config_dataclasses() -> None:
    tables = parse_parameter_tables(PARAMETERS.read_text(encoding="utf-8"))
    assert set(tables) == set(STAGES), "one '## [stage]' table per config stage"
    for stage, cls in STAGES.items():
        fields = {f.name for f in dataclasses.fields(cls)}
        listed = set(tables[stage])
        assert listed == fields, (
            f"[{stage}]: missing from docs/parameters.md {sorted(fields - listed)}, "
            f"not in pointrig.config {sorted(listed - fields)}")
        defaults = cls()
        for name, written in tables[stage].items():
            want = getattr(defaults, name)
            got = parse_default(written)
            assert same_value(got, want), f"[{stage}] {name}: page says {written}, config {want!r}"


def test_parser_reads_what_it_should() -> None:
    """The parser itself, on a page built here: it finds the rows, keeps the stages apart and
    refuses a duplicate, so the comparison above cannot pass on an empty parse."""
    page = ("# P\n\n## [registration]\n\n| field | symbol | default | unit | meaning |\n"
            "|---|---|---|---|---|\n| `omega` | `omega` | `0.01` | — | outlier weight |\n"
            "| `rest_frame` | — | `\"fit\"` | frame | rest pose |\n\n## [structure]\n\n"
            "| `camera_position` | — | `[0.0, 0.0, 0.0]` | m | camera |\n")
    tables = parse_parameter_tables(page)
    assert tables == {"registration": {"omega": "0.01", "rest_frame": '"fit"'},
                      "structure": {"camera_position": "[0.0, 0.0, 0.0]"}}
    assert parse_default("[0.0, 0.0, 0.0]") == (0.0, 0.0, 0.0)
    assert parse_default("1e5") == 1e5 and parse_default("false") is False
    assert not same_value(parse_default("2"), 2.0) and same_value(parse_default("2.0"), 2.0)
    with pytest.raises(ValueError, match="twice"):
        parse_parameter_tables(page + "| `camera_position` | — | `[1.0, 0.0, 0.0]` | m | x |\n")


def test_sizes() -> None:
    readme = README.read_text(encoding="utf-8").splitlines()
    assert len(readme) <= 250, f"README.md has {len(readme)} lines (at most 250)"
    long = [n for n, line in enumerate(readme, 1) if len(line) > 200]
    assert not long, f"README.md lines over 200 characters: {long}"
    docs = {p.name: len(p.read_text(encoding="utf-8").splitlines()) for p in DOCS.rglob("*.md")}
    assert sum(docs.values()) <= 1500, f"docs/ has {sum(docs.values())} lines (at most 1500)"


#: words the user-facing pages must not contain (case-insensitive): the name of a unit of work
#: and the scratch folder, spelled in parts so that a search of the tree for them finds none here
FORBIDDEN = ("ses" + "sion", "/" + "tmp/")


@pytest.mark.parametrize("path", doc_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_work_log_wording_or_scratch_paths(path: Path) -> None:
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        for word in FORBIDDEN:
            assert word not in line.lower(), f"{path.name}:{n}: {word!r} in {line.strip()}"


def _anchors(page: Path) -> set[str]:
    """GitHub-style anchors of a Markdown page's headings."""
    out = set()
    for line in page.read_text(encoding="utf-8").splitlines():
        if m := re.match(r"^#+\s+(.*)$", line):
            slug = re.sub(r"[^\w\- ]", "", m.group(1).strip().lower()).replace(" ", "-")
            out.add(slug)
    return out


@pytest.mark.parametrize("path", doc_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_links_into_docs_resolve(path: Path) -> None:
    """Every relative link that lands in docs/ (or is README.md's picture) names an existing
    file, and an anchor on a Markdown page names one of its headings."""
    text = path.read_text(encoding="utf-8")
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"^[a-z]+:", target):
            continue  # an external address
        file, _, anchor = target.partition("#")
        dest = (path.parent / file).resolve() if file else path
        if DOCS.resolve() not in dest.parents and dest != path:
            continue  # outside docs/: other parts of the tree own it
        assert dest.exists(), f"{path.name}: link to missing {target}"
        if anchor and dest.suffix == ".md":
            assert anchor in _anchors(dest), f"{path.name}: no heading for #{anchor} in {file}"
