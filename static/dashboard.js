// The dashboard: polls GET /overview about once a second and redraws two tables. Live sessions
// (where explorers are and were) are listed for an operator's key only: the page asks for it
// and keeps it in this tab's sessionStorage; without it, the figures per domain. Each session
// shows what its advisor believes as its strategy says it (plain words first, the paper's
// symbol second, coloured by the strategy's tone) and where its advice leads. The sessions
// table sorts by any column (a click on its heading); with the admin key, a session can be
// ended from its row (DELETE /sessions/{id}); with the read-only key (the overview's role)
// the End buttons are disabled, saying why; a refusal is shown with the service's reason.
"use strict";

(() => {
  const { ACTIONS, ARROWS, fetchJSON, watchViewerLink, fmt, barOf, figureText, beliefsText,
          destinationText, refuse } = MazeUI;
  const POLL_MS = 1000;
  const KEY = "advisor-operator-key";
  const $ = (id) => document.getElementById(id);
  let refused = null; // the service's reason, when the key given was refused
  let last = null; // the last answer, to redraw at once when the sort changes
  const sort = { key: null, dir: 1 }; // null: the service's order (most recently active first)
  const ending = new Set(); // sessions whose DELETE is under way

  function cell(text, className = "") {
    const td = document.createElement("td");
    td.textContent = text;
    if (className) td.className = className;
    return td;
  }

  function emptyRow(columns, text) {
    const tr = document.createElement("tr");
    tr.className = "empty";
    const td = cell(text);
    td.colSpan = columns;
    tr.append(td);
    return tr;
  }

  /** What the advisor believes, as its strategy says it: the figure that says most now (a
   *  bar in the strategy's tone, plain words, the paper's symbol); every figure in the
   *  tooltip. A service without beliefs: the paper's P(M1|H). */
  function believes(s) {
    const td = document.createElement("td");
    td.className = "left believes";
    const b = s.beliefs;
    if (!b) {
      td.append(barOf(s.p_normal, s.p_normal < 0.5 ? "bad" : "good"),
                document.createTextNode(`P(M1|H) ${fmt(s.p_normal)}`));
      return td;
    }
    const f = b.figures[b.headline];
    td.dataset.tone = f.tone;
    const text = document.createElement("span");
    text.className = `tone-${f.tone}`;
    text.textContent = figureText(f);
    td.append(barOf(f.p, f.tone), text);
    td.title = beliefsText(b);
    return td;
  }

  function leadsTo(s) {
    const to = s.beliefs && s.beliefs.leads_to;
    const td = cell(to ? destinationText(to) : "–", "left");
    if (to) td.title = `Its advice leads to [${to.cell.join(", ")}]`;
    return td;
  }

  /** A small line of recent P(M1|H) values (knows the way) on a fixed 0..1 scale, a dotted
   *  line at 0.5. */
  function sparklineOf(values) {
    const w = 90, h = 22;
    const ns = "http://www.w3.org/2000/svg";
    const svg = document.createElementNS(ns, "svg");
    svg.setAttribute("class", "spark");
    svg.setAttribute("width", w);
    svg.setAttribute("height", h);
    svg.setAttribute("viewBox", `0 0 ${w} ${h}`);
    const y = (v) => (1 - v) * (h - 2) + 1;
    const half = document.createElementNS(ns, "line");
    Object.entries({ x1: 0, x2: w, y1: y(0.5), y2: y(0.5), class: "half" })
      .forEach(([k, v]) => half.setAttribute(k, v));
    svg.append(half);
    if (values.length > 1) {
      const line = document.createElementNS(ns, "polyline");
      const points = values.map((v, i) => `${(i * (w - 2)) / (values.length - 1) + 1},${y(v)}`);
      line.setAttribute("points", points.join(" "));
      line.setAttribute("class", "line");
      svg.append(line);
    }
    return svg;
  }

  function sparkline(values) {
    const td = document.createElement("td");
    td.className = "left";
    td.append(sparklineOf(values));
    return td;
  }

  function lastAdvice(advice) {
    if (!advice) return cell("–", "left");
    const best = ACTIONS.reduce((a, b) => (advice.advice[b] > advice.advice[a] ? b : a));
    return cell(`step ${advice.step} at [${advice.state.join(", ")}]: ` +
      `${ARROWS[best]} ${best} ${Math.round(100 * advice.advice[best])}%`, "left last");
  }

  // The advising strategy; goal_aware sessions also list the goals still possible.
  function strategy(s) {
    const td = cell(s.strategy, "left");
    if (s.goals) {
      const open = s.goals.filter((g) => !g.ruled_out).length;
      td.textContent += ` (${open}/${s.goals.length} goals)`;
      td.title = s.goals.map((g) => `[${g.goal.join(", ")}]: ${g.ruled_out ? "ruled out" : g.p.toFixed(2)}`).join("\n");
    }
    return td;
  }

  // What the session may still be advised: muted, its budget's pieces left, or no limit.
  function adviceLeft(s) {
    if (s.muted) return "muted";
    const b = s.budget;
    if (!b) return "no limit";
    const parts = [];
    if (b.left !== null) parts.push(`${b.left} of ${b.total}`);
    if (b.left_this_minute !== null) parts.push(`${b.left_this_minute}/min of ${b.per_minute}`);
    return parts.join(", ");
  }

  function adviceLeftCell(s) {
    const td = cell(adviceLeft(s), "left");
    td.title = s.muted ? "The visitor asked for no more advice" :
      "Advice this session may still be given (its budget: in all, and this minute)";
    return td;
  }

  function walkLink(d) {
    const td = document.createElement("td");
    td.className = "left";
    const a = document.createElement("a");
    a.href = `/walk?domain=${encodeURIComponent(d.name)}`;
    a.textContent = "walk it";
    td.append(a);
    return td;
  }

  // One button per session, kept across redraws: a click is not lost to the next poll's rows.
  const buttons = new Map();
  const READ_ONLY = "This key can only read: ending a session needs the admin key";

  function endButton(s) {
    const td = document.createElement("td");
    td.className = "left";
    let button = buttons.get(s.session_id);
    if (!button) {
      button = document.createElement("button");
      button.type = "button";
      button.className = "end";
      button.addEventListener("click", () => endSession(s.session_id));
      buttons.set(s.session_id, button);
    }
    button.textContent = ending.has(s.session_id) ? "Ending…" : "End";
    if (last && last.role === "operator") {
      refuse(button, READ_ONLY);
    } else {
      button.disabled = ending.has(s.session_id);
      button.title = "End this session (DELETE /sessions/{id}, the admin key)";
      button.removeAttribute("aria-disabled");
    }
    td.append(button);
    return td;
  }

  // Each column: heading, unit (shown under it), how a cell is drawn, and the value it sorts by
  // (none: not sortable). Units: κ, the KL and the cost are in nats; cost = κ × advice given.
  const DOMAIN_COLUMNS = [
    { label: "Name", left: true, draw: (d) => cell(d.name, "left") },
    { label: "Size", unit: "rows × cols", draw: (d) => cell(`${d.rows}×${d.cols}`) },
    { label: "Free cells", unit: "cells", draw: (d) => cell(d.n_states) },
    { label: "Expert trajectories", unit: "stored", draw: (d) => cell(d.trajectories) },
    { label: "Live sessions", unit: "sessions", draw: (d) => cell(d.sessions) },
    { label: "Steps", unit: "moves, all sessions", draw: (d) => cell(d.steps) },
    { label: "Advice per 100", unit: "decisions", draw: (d) => cell(fmt(d.advice_per_100, 1)) },
    { label: "Looking lost", unit: "sessions (P(M1|H) < 0.5)", draw: (d) => cell(d.looking_lost) },
    { label: "", left: true, draw: walkLink },
  ];
  const SESSION_COLUMNS = [
    { key: "session", label: "Session", left: true, draw: (s) => cell(s.session_id, "left mono"), value: (s) => s.session_id },
    { key: "domain", label: "Domain", left: true, draw: (s) => cell(s.domain, "left"), value: (s) => s.domain },
    { key: "type", label: "Type", left: true, draw: (s) => cell(s.agent_type || "–", "left"), value: (s) => s.agent_type || "" },
    { key: "strategy", label: "Strategy", left: true, draw: strategy, value: (s) => s.strategy },
    { key: "kappa", label: "Price of advice", unit: "κ, nats", draw: (s) => cell(s.kappa), value: (s) => s.kappa },
    { key: "steps", label: "Steps", unit: "moves", draw: (s) => cell(s.steps), value: (s) => s.steps },
    { key: "position", label: "Position", unit: "[row, col] ([floor, row, col])", draw: (s) => cell(`[${s.position.join(", ")}]`), value: (s) => s.position.reduce((v, x) => v * 1e5 + x, 0) },
    { key: "floor", label: "Floor", unit: "buildings of floors", left: true, draw: (s) => cell(s.floor || "–", "left"), value: (s) => (s.floor ? s.position[0] : -1) },
    { key: "p", label: "Advisor believes", unit: "plain words (the paper's symbol)", left: true, draw: believes, value: (s) => s.p_normal },
    { key: "leads", label: "Advice leads to", unit: "destination", left: true, draw: leadsTo, value: (s) => (s.beliefs && s.beliefs.leads_to ? s.beliefs.leads_to.goal : -1) },
    { key: "recent", label: "Knows the way, lately", unit: "P(M1|H), recent decisions", left: true, draw: (s) => sparkline(s.p_normal_history || []) },
    { key: "advice", label: "Advice", unit: "given", draw: (s) => cell(s.advice_count), value: (s) => s.advice_count },
    { key: "cost", label: "Cost", unit: "κ × advice, nats", draw: (s) => cell(fmt(s.total_cost, 2)), value: (s) => s.total_cost },
    { key: "per100", label: "Per 100", unit: "decisions", draw: (s) => cell(fmt(s.advice_per_100, 1)), value: (s) => s.advice_per_100 },
    { key: "left", label: "Advice left", unit: "budget", left: true, draw: adviceLeftCell, value: adviceLeft },
    { key: "last", label: "Last advice", unit: "step, cell", left: true, draw: (s) => lastAdvice(s.last_advice), value: (s) => (s.last_advice ? s.last_advice.step : -1) },
    { key: "end", label: "", left: true, draw: endButton },
  ];

  function heading(column, sortable) {
    const th = document.createElement("th");
    if (column.left) th.className = "left";
    th.dataset.column = column.key || "";
    const label = sortable ? document.createElement("button") : document.createElement("span");
    label.textContent = column.label;
    if (sortable) {
      label.type = "button";
      label.className = "sort";
      label.title = `Sort by ${column.label}`;
      label.addEventListener("click", () => sortBy(column.key));
      const on = sort.key === column.key;
      th.setAttribute("aria-sort", on ? (sort.dir > 0 ? "ascending" : "descending") : "none");
      const mark = document.createElement("span");
      mark.className = "mark";
      mark.textContent = on ? (sort.dir > 0 ? " ▲" : " ▼") : "";
      label.append(mark);
    }
    th.append(label);
    if (column.unit) {
      const unit = document.createElement("span");
      unit.className = "unit";
      unit.textContent = column.unit;
      th.append(unit);
    }
    return th;
  }

  function renderHeadings() {
    $("domains").tHead.rows[0].replaceChildren(...DOMAIN_COLUMNS.map((c) => heading(c, false)));
    $("sessions").tHead.rows[0].replaceChildren(
      ...SESSION_COLUMNS.map((c) => heading(c, Boolean(c.value))));
    const column = SESSION_COLUMNS.find((c) => c.key === sort.key);
    $("sort-note").textContent = column
      ? `sorted by ${column.label}, ${sort.dir > 0 ? "ascending" : "descending"}.`
      : "sorted as the service lists them: most recently active first.";
  }

  function sortBy(key) {
    if (sort.key === key) sort.dir = -sort.dir;
    else Object.assign(sort, { key, dir: 1 });
    renderHeadings();
    if (last) renderSessions(last.sessions, last.total_sessions, last.detail);
  }

  /** The sessions in the order chosen; ties keep the service's order. */
  function sorted(sessions) {
    const column = SESSION_COLUMNS.find((c) => c.key === sort.key);
    if (!column) return sessions;
    const keyed = sessions.map((s, i) => [column.value(s), i, s]);
    keyed.sort((a, b) => {
      const order = typeof a[0] === "string" ? a[0].localeCompare(b[0]) : a[0] - b[0];
      return sort.dir * order || a[1] - b[1];
    });
    return keyed.map((k) => k[2]);
  }

  function renderDomains(domains) {
    const body = $("domains").tBodies[0];
    if (!domains.length) {
      body.replaceChildren(emptyRow(DOMAIN_COLUMNS.length, "No domains."));
      return;
    }
    body.replaceChildren(...domains.map((d) => {
      const tr = document.createElement("tr");
      tr.dataset.domain = d.name;
      tr.append(...DOMAIN_COLUMNS.map((c) => c.draw(d)));
      return tr;
    }));
  }

  /** What the key may do, said once above the table (each End button's tooltip says it too). */
  function showRole(role) {
    const note = $("role-note");
    note.hidden = role !== "operator";
    note.textContent = role === "operator"
      ? "This key can only read: you see the live sessions; ending one needs the admin key." : "";
  }

  function renderSessions(sessions, total, detail) {
    showRole(last ? last.role : null);
    const body = $("sessions").tBodies[0];
    const columns = SESSION_COLUMNS.length;
    $("session-total").textContent = total > sessions.length
      ? `(${total} live; the ${sessions.length} most recently active shown)` : `(${total} live)`;
    if (!detail) {
      body.replaceChildren(emptyRow(columns, refused
        ? `The key was refused (${refused}): enter the operator key to see live sessions.`
        : "Live sessions are shown with the operator key (above)."));
      return;
    }
    if (!sessions.length) {
      body.replaceChildren(emptyRow(columns, "No live sessions. Walk the maze, or run python -m app simulate."));
      return;
    }
    const listed = new Set(sessions.map((s) => s.session_id));
    for (const id of buttons.keys()) if (!listed.has(id)) buttons.delete(id);
    body.replaceChildren(...sorted(sessions).map((s) => {
      const tr = document.createElement("tr");
      tr.dataset.sessionId = s.session_id;
      tr.append(...SESSION_COLUMNS.map((c) => {
        const td = c.draw(s);
        td.dataset.column = c.key;
        return td;
      }));
      return tr;
    }));
  }

  function say(text, isError) {
    const el = $("session-message");
    el.textContent = text;
    el.classList.toggle("error", isError);
    el.hidden = false;
  }

  async function endSession(id) {
    if (ending.has(id)) return;
    ending.add(id);
    if (last) renderSessions(last.sessions, last.total_sessions, last.detail);
    try {
      const ended = await fetchJSON(`/sessions/${encodeURIComponent(id)}`, {
        method: "DELETE", headers: { "X-API-Key": key() },
      });
      say(`Session ${id} ended after ${ended.steps} steps (${ended.advice_count} pieces of ` +
          `advice, cost ${fmt(ended.total_cost, 2)} nats).`, false);
      if (last) last.sessions = last.sessions.filter((s) => s.session_id !== id);
    } catch (err) {
      say(`Could not end session ${id}: ${err.message}`, true);
    } finally {
      ending.delete(id);
      if (last) renderSessions(last.sessions, last.total_sessions, last.detail);
    }
  }

  function key() {
    return sessionStorage.getItem(KEY) || "";
  }

  async function overview() {
    const given = key();
    if (!given) return fetchJSON("/overview");
    try {
      const answer = await fetchJSON("/overview", { headers: { "X-API-Key": given } });
      refused = null;
      return answer;
    } catch (err) {
      if (!err.message.startsWith("403")) throw err;
      refused = err.message;
      return fetchJSON("/overview"); // the figures anyone may see
    }
  }

  function showKeyForm() {
    const known = Boolean(key());
    $("forget-key").hidden = !known;
    $("key").placeholder = known ? "(a key is set for this tab)" : "X-API-Key (data/operator_key)";
  }

  $("key-form").addEventListener("submit", (event) => {
    event.preventDefault();
    const value = $("key").value.trim();
    if (value) sessionStorage.setItem(KEY, value);
    $("key").value = "";
    showKeyForm();
  });
  $("forget-key").addEventListener("click", () => {
    sessionStorage.removeItem(KEY);
    refused = null;
    showKeyForm();
  });
  showKeyForm();

  // the legend's samples, drawn by the same functions as the table's cells
  for (const tone of ["good", "neutral", "bad"]) {
    document.querySelector(`[data-sample="bar-${tone}"]`).append(barOf(0.8, tone));
  }
  document.querySelector('[data-sample="sparkline"]')
    .append(sparklineOf([0.9, 0.85, 0.6, 0.3, 0.1, 0.15, 0.45, 0.7, 0.9]));
  renderHeadings();

  async function poll() {
    try {
      const answer = await overview();
      last = answer;
      renderDomains(answer.domains);
      renderSessions(answer.sessions, answer.total_sessions, answer.detail);
      $("status").textContent = `Updated ${new Date().toLocaleTimeString()}`;
      $("status").classList.remove("error");
    } catch (err) {
      $("status").textContent = `Cannot reach the service (${err.message}); retrying…`;
      $("status").classList.add("error");
    } finally {
      setTimeout(poll, POLL_MS);
    }
  }

  // What the service relies on (GET /health: 503 when the database or Redis is down, with the
  // same list), in plain words; refreshed every few seconds.
  const DEPENDENCY_NAMES = { database: "Database", redis: "Redis", mqtt: "MQTT bridge", viewer: "3D viewer" };
  const DEPENDENCY_MS = 5000;

  async function dependencies() {
    const strip = $("dependencies");
    try {
      const response = await fetch("/health");
      const body = await response.json().catch(() => null);
      const deps = (body && body.dependencies) || {};
      strip.replaceChildren(...Object.entries(DEPENDENCY_NAMES).filter(([key]) => key in deps)
        .map(([key, name]) => {
          const d = deps[key];
          const item = document.createElement("span");
          item.className = `dependency ${d.state.replace(/ /g, "-")}${d.required ? " required" : ""}`;
          item.dataset.dependency = key;
          item.textContent = `${name}: ${d.state}`;
          item.title = d.detail || (d.required ? "The service cannot work without it" :
            "The service works without it");
          return item;
        }));
      strip.classList.toggle("error", !response.ok);
    } catch (err) {
      strip.textContent = `Cannot read the service's health (${err.message})`;
      strip.classList.add("error");
    } finally {
      setTimeout(dependencies, DEPENDENCY_MS);
    }
  }

  poll();
  dependencies();
  watchViewerLink($("viewer-link"));
})();
