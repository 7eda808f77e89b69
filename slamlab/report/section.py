"""One optional per-run section of the run report (`extra_sections`): what it draws."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True, slots=True)
class ExtraSection:
    """One section: `id` (the HTML anchor), `title`, figures as (data URI, alt text), a note
    under them and an optional table (`columns`, `rows` of text cells)."""

    id: str
    title: str
    images: list[tuple[str, str]] = field(default_factory=list)
    note: str = ""
    columns: list[str] = field(default_factory=list)
    rows: list[list[str]] = field(default_factory=list)
