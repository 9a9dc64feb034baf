"""leaderboard.html: the leaderboard as one self-contained page to browse (`smtrain leaderboard
--html`). The table is written here, in HTML, every value escaped; a short script sorts it by any
column and filters it by task and mode. The view is held in the address's fragment
(`#sort=d_metric&task=grid&mode=MM`), so a view can be linked to, and a header's click or a
filter's change only sets the fragment. The figure is inlined, and the page's security policy
forbids it to load anything: no server and no network are needed to view it, nor used."""

from __future__ import annotations

import base64
import html
import inspect
import os
from pathlib import Path
from typing import Any

from smspace.bench import differences
from smspace.bench.verify import Result
from smspace.common.errors import SmspaceError
from smspace.metrics.scores import SCORES
from smspace.metrics.spread import as_cell

POLICY = "default-src 'none'; img-src data:; style-src 'unsafe-inline'; script-src 'unsafe-inline'"

STYLE = """
body { font: 14px system-ui, sans-serif; margin: 1.5em; color: #222; }
table { border-collapse: collapse; margin: 1em 0; }
th, td { border: 1px solid #ccc; padding: 3px 7px; text-align: left; vertical-align: top; }
th[data-key] { cursor: pointer; background: #f3f3f3; }
th[aria-sort=ascending]::after { content: " \\25B2"; }
th[aria-sort=descending]::after { content: " \\25BC"; }
td .ci { color: #777; font-size: 85%; }
td .mark { font-weight: 600; color: #05a; }
tr[hidden] { display: none; }
img { max-width: 100%; }
"""

SCRIPT = """
(function () {
  var body = document.querySelector("#board tbody");
  function view() {
    var v = {};
    location.hash.replace(/^#/, "").split("&").forEach(function (kv) {
      var i = kv.indexOf("=");
      if (i > 0) v[decodeURIComponent(kv.slice(0, i))] = decodeURIComponent(kv.slice(i + 1));
    });
    return v;
  }
  function show(v) {
    var rows = Array.prototype.slice.call(body.rows);
    rows.forEach(function (r) {
      r.hidden = (v.task && r.dataset.task !== v.task) || (v.mode && r.dataset.mode !== v.mode) ? true : false;
    });
    if (v.sort) {
      var col = document.querySelector('th[data-key="' + v.sort + '"]');
      if (col) {
        var at = col.cellIndex, sign = v.dir === "desc" ? -1 : 1;
        rows.sort(function (a, b) {
          var x = a.cells[at].dataset.v, y = b.cells[at].dataset.v;
          var nx = parseFloat(x), ny = parseFloat(y);
          if (isNaN(nx) !== isNaN(ny)) return isNaN(nx) ? 1 : -1;  /* empty cells last */
          var c = (!isNaN(nx) && !isNaN(ny)) ? nx - ny : (x < y ? -1 : x > y ? 1 : 0);
          return sign * c || (a.dataset.order - b.dataset.order);
        });
        rows.forEach(function (r) { body.appendChild(r); });
      }
    }
    document.querySelectorAll("th[data-key]").forEach(function (th) {
      if (th.dataset.key === v.sort) th.setAttribute("aria-sort", v.dir === "desc" ? "descending" : "ascending");
      else th.removeAttribute("aria-sort");
    });
    ["task", "mode"].forEach(function (k) { document.getElementById(k).value = v[k] || ""; });
  }
  function set(change) {
    var v = view(), k;
    for (k in change) { if (change[k]) v[k] = change[k]; else delete v[k]; }
    location.hash = Object.keys(v).map(function (k) {
      return encodeURIComponent(k) + "=" + encodeURIComponent(v[k]);
    }).join("&");
  }
  document.querySelectorAll("th[data-key]").forEach(function (th) {
    th.addEventListener("click", function () {
      var v = view();
      set({sort: th.dataset.key, dir: v.sort === th.dataset.key && v.dir !== "desc" ? "desc" : "asc"});
    });
  });
  ["task", "mode"].forEach(function (k) {
    document.getElementById(k).addEventListener("change", function (e) { var c = {}; c[k] = e.target.value; set(c); });
  });
  window.addEventListener("hashchange", function () { show(view()); });
  show(view());
})();
"""


def page(
    table: list[dict[str, Any]],
    results: list[Result],
    shown: dict[str, str],
    head: dict[str, Any],
    figure: bytes,
    out: Path,
    ranked: list[dict[str, Any]] = (),
    budget_figure: bytes | None = None,
) -> str:
    """The page's text: one row per entry, task and mode; a column per score (mean ± std, its
    interval, its marks), the wall time and the result's files; and, where results carry scores at
    earlier evaluations, whether each ranking is settled (bench/budget.py)."""
    e = html.escape
    shown_rows = _rows(table, results, shown)
    tasks = sorted({c["task"] for c in table})
    modes = sorted({c["mode"] for c in table})
    versions = ", ".join(f"v{v}" for v in head["versions"])
    title = f"smspace-bench: {head['suite']} ({versions})"
    heads = ['<th data-key="entry">entry</th>', '<th data-key="task">task</th>', '<th data-key="mode">mode</th>']
    heads += [f'<th data-key="{e(k)}">{e(SCORES[k].title)} {SCORES[k].arrow}</th>' for k in SCORES]
    heads += ['<th data-key="wall_s">wall time (s)</th>', "<th>files</th>"]
    body = []
    for order, (entry, task, mode, cells, result) in enumerate(shown_rows):
        tds = [f'<td data-v="{e(entry)}">{e(entry)}</td>', f'<td data-v="{e(task)}">{e(task)}</td>',
               f'<td data-v="{e(mode)}">{e(mode)}</td>']  # fmt: skip
        tds += [_score_cell(cells.get(k)) for k in SCORES]
        tds.append(f'<td data-v="{result.wall_s:.6g}">{"" if result.wall_complete else "≥ "}{result.wall_s:.0f}</td>')
        tds.append(f"<td>{_link(result.where, out)}</td>")
        body.append(
            f'<tr data-entry="{e(entry)}" data-task="{e(task)}" data-mode="{e(mode)}" data-order="{order}">'
            + "".join(tds)
            + "</tr>"
        )
    options = {
        name: "".join(f'<option value="{e(v)}">{e(v)}</option>' for v in values)
        for name, values in (("task", tasks), ("mode", modes))
    }
    entries = "".join(
        f"<dt>{e(name)}</dt><dd>{e(description)} <small>code {e(code)}</small></dd>"
        for name, description, code in _entries(results, shown)
    )
    protocol = "".join(f"<li>{e(k)}: {e(str(v))}</li>" for k, v in head["differences"].items())
    image = base64.b64encode(figure).decode()
    budget = _budget(ranked, budget_figure)
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8">
<meta http-equiv="Content-Security-Policy" content="{POLICY}">
<title>{e(title)}</title><style>{STYLE}</style></head>
<body>
<h1>{e(title)}</h1>
<p>{len(results)} result(s). Each cell: mean ± standard deviation over worlds, its 95 % bootstrap interval,
and its marks: <b>best</b>, the best mean of its task, mode and score; <b>floor</b>, the random encoder's;
<b>≈best</b>, <b>≈floor</b>: not told apart from them by a paired t-test over the shared worlds, Holm-corrected
over the entries. Click a heading to sort; the address keeps the view, to link to.</p>
<p><label>task <select id="task"><option value="">all</option>{options["task"]}</select></label>
<label>mode <select id="mode"><option value="">all</option>{options["mode"]}</select></label></p>
<table id="board"><thead><tr>{"".join(heads)}</tr></thead>
<tbody>
{chr(10).join(body)}
</tbody></table>
<h2>The figure</h2>
<img alt="each entry's mean and spread over worlds, per task and mode, one panel per score"
 src="data:image/png;base64,{image}">
{budget}<h2>The entries</h2><dl>{entries}</dl>
<h2>How differences are told</h2><ul>{protocol}</ul>
<script>{SCRIPT}</script>
</body></html>
"""


def _rows(
    table: list[dict[str, Any]], results: list[Result], shown: dict[str, str]
) -> list[tuple[str, str, str, dict[str, dict[str, Any]], Result]]:
    """(entry, task, mode, its cells by score, the result they come from), sorted."""
    owner = {(shown[r.where], r.task): r for r in results}
    rows: dict[tuple[str, str, str], dict[str, dict[str, Any]]] = {}
    for cell in table:
        rows.setdefault((cell["entry"], cell["task"], cell["mode"]), {})[cell["score"]] = cell
    return [(*key, cells, owner[key[0], key[1]]) for key, cells in sorted(rows.items())]


def _score_cell(cell: dict[str, Any] | None) -> str:
    if cell is None:
        return '<td data-v="">—</td>'
    text = html.escape(as_cell(cell["mean"], cell["std"]))
    interval = differences.interval_text(cell)
    if interval is not None:
        text += f' <span class="ci">{html.escape(interval)}</span>'
    said = differences.marks(cell)
    if said:
        text += f' <span class="mark">{html.escape(said)}</span>'
    return f'<td data-v="{cell["mean"]:.17g}">{text}</td>'


def _link(where: str, out: Path) -> str:
    """A result's folder, relative to the page where it is a local folder (so the page and the
    results move together); a URL is shown, not linked (the page loads nothing)."""
    if "://" in where:
        return html.escape(where)
    target = os.path.relpath(Path(where).resolve(), out.resolve())
    return f'<a href="{html.escape(Path(target).as_posix(), quote=True)}/">{html.escape(where)}</a>'


def _entries(results: list[Result], shown: dict[str, str]) -> list[tuple[str, str, str]]:
    """(entry, what it is, the code that made it) per row, from the entry's own docstring."""
    found = {shown[r.where]: (_description(r.entry.split(" (")[0]), r.code) for r in results}
    return [(name, *found[name]) for name in sorted(found)]


def _description(name: str) -> str:
    from smspace.bench.representations import REPRESENTATIONS
    from smspace.train.config import MODELS

    try:
        thing = REPRESENTATIONS[name] if name in REPRESENTATIONS else MODELS.get(name)
    except SmspaceError:  # a plugin no longer installed: its results still show, undescribed
        return "(its code is not installed here)"
    doc = inspect.getdoc(thing) or ""
    return " ".join(doc.split("\n\n")[0].split()) or "(no description)"


def _budget(ranked: list[dict[str, Any]], figure: bytes | None) -> str:
    """The budget's section: per task, mode and score, settled or not, and the last ranking."""
    if not ranked:
        return ""
    e = html.escape
    rows = []
    for r in ranked:
        said = "yes" if r["settled"] else f"no (changed at step {r['last_change']})"
        cells = (r["task"], r["mode"], SCORES[r["score"]].title, said, " > ".join(r["order"][-1]))
        rows.append("<tr>" + "".join(f"<td>{e(str(c))}</td>" for c in cells) + "</tr>")
    image = (
        f'<img alt="D_metric and the probe against steps, per task and mode, a line per entry" '
        f'src="data:image/png;base64,{base64.b64encode(figure).decode()}">'
        if figure
        else ""
    )
    return (
        "<h2>Budget: the ranking against steps</h2><p>Settled: the last evaluation left the ranking of the "
        "one before unchanged.</p><table><thead><tr><th>task</th><th>mode</th><th>score</th><th>settled</th>"
        f"<th>ranking at the last step (best first)</th></tr></thead><tbody>{''.join(rows)}</tbody></table>{image}\n"
    )
