"""docs/plugins.md is generated from the hooks and contracts; it must be what the code says now."""

from __future__ import annotations

from conftest import REPO

from magline.testing.reference import generate


def test_the_plugin_reference_is_current():
    written = (REPO / "docs" / "plugins.md").read_text(encoding="utf-8")
    assert written == generate(), "docs/plugins.md is stale: run  python -m magline.testing.reference > docs/plugins.md"


def test_the_reference_holds_every_hook_and_the_lifecycle_contracts():
    text = generate()
    from test_hook_guard import HOOKS

    assert all(f"### `{hook}`" in text for hook in HOOKS)
    for contract in ("in RAM *and* storage", "never invent readings", "gives up at the first error",
                     "persistence.method", "Run ids:", "check_result_sink"):
        assert contract in text, contract


def test_the_reference_lists_every_fixture_of_the_testing_kit():
    """Issue 66: the contract page's "Fixtures" section was empty (pytest wraps a fixture in an object that is
    not a function, and the generator looked for functions)."""
    import magline.testing.plugin as kit

    text = generate()
    section = text.split("### Fixtures (pytest plugin `magline.testing.plugin`)", 1)[1].split("## ", 1)[0]
    fixtures = [n for n in dir(kit) if n.startswith("magline_")]
    assert fixtures and all(f"- `{name}`: " in section for name in fixtures)


def test_the_reference_gives_every_public_type_s_fields_and_the_face_holds_them():
    """Issue 66: the fields of SampleChunk, ImuSeries and UnitInfo were not on the contract page (a
    temperature in the stream changes how the fit tests for warm-up, unsaid); Numeric, Verdict and Measurement
    had no docs; Array and Json were not on the face."""
    import magline.plugin as face

    text = generate()
    section = text.split("## The public types", 1)[1].split("## Testing your plugin", 1)[0]
    for name in ("SampleChunk", "ImuSeries", "UnitInfo", "Numeric", "Array", "Json", "Verdict"):
        assert f"### `{name}`" in section and hasattr(face, name)
    assert "| `temp_c` | `NDArray \\| None` | `None` | the sensor's temperature per reading" in section
    assert "REVIEW inside but within its marginal" in section and "(undocumented)" not in section


def test_every_link_and_named_file_in_the_docs_is_in_the_repository():
    """A reader with the repository alone follows every relative link and every backquoted path that
    leaves it (``../shared/reference/…`` was named to people who do not have it)."""
    import re

    repo = REPO
    broken = []
    for page in [repo / "README.md", *sorted((repo / "docs").glob("*.md"))]:
        text = page.read_text(encoding="utf-8")
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text):
            if not re.match(r"[a-z]+://|mailto:", target) and not (page.parent / target).exists():
                broken.append(f"{page.name}: ({target})")
        broken += [f"{page.name}: `{path}`" for path in re.findall(r"`(\.\./[^`\s]+)`", text)]
    assert broken == []


PARAGRAPH_MOST = 1200  # characters a reader takes in at once (the page check the docs are held to)


def _paragraphs(text: str) -> list[str]:
    """Prose paragraphs of a markdown page: code blocks, headings and tables left out; a list item is its own."""
    import re

    out: list[str] = []
    current: list[str] = []
    inside = False
    for line in text.split("\n"):
        if line.startswith("```"):
            inside = not inside
        if inside or line.startswith("```") or not line.strip() or line.startswith(("#", "|")) or (
                re.match(r"\s*([-*]|\d+\.)\s", line) and current):
            if current:
                out.append(" ".join(current))
                current = []
            if inside or line.startswith("```") or not line.strip() or line.startswith(("#", "|")):
                continue
        current.append(line.strip())
    if current:
        out.append(" ".join(current))
    return out


def test_every_page_s_paragraphs_are_short_enough_to_take_in_and_say_no_work_history():
    """The docs had a paragraph of 8,300 characters citing "session 30" and "issue 49": every paragraph of
    the README and docs/ (the generated plugin reference included) is at most PARAGRAPH_MOST characters, and
    no user page cites a session or an issue — the reasoning and its measurements, dated, are
    docs/design-notes.md's."""
    import re

    long, history = [], []
    for page in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]:
        text = page.read_text(encoding="utf-8")
        long += [f"{page.name}: {len(p)} chars: {p[:60]}…" for p in _paragraphs(text) if len(p) > PARAGRAPH_MOST]
        if page.name != "design-notes.md":
            history += [f"{page.name}: {m}" for m in re.findall(r"\b(?:session|issue) #?\d+", text, re.I)]
    assert long == [] and history == []
    # the check sees a long paragraph, and a list item as its own
    assert [len(p) for p in _paragraphs("a " * 700 + "\n\n- x\n- y\n```\n" + "b " * 900 + "\n```")] == [1399, 3, 3]
