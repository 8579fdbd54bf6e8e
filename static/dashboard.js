// The dashboard: polls GET /overview about once a second and redraws two tables. Live sessions
// (where explorers are and were) are listed for an operator's key only: the page asks for it
// and keeps it in this tab's sessionStorage; without it, the figures per domain.
"use strict";

(() => {
  const { ACTIONS, ARROWS, fetchJSON, showViewerLink, fmt } = MazeUI;
  const POLL_MS = 1000;
  const KEY = "advisor-operator-key";
  const $ = (id) => document.getElementById(id);
  let refused = null; // the service's reason, when the key given was refused

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

  function bar(p) {
    const td = document.createElement("td");
    td.className = "left";
    const outer = document.createElement("span");
    outer.className = p < 0.5 ? "bar lost" : "bar";
    const inner = document.createElement("span");
    inner.style.width = `${Math.round(100 * Math.min(1, Math.max(0, p)))}%`;
    outer.append(inner);
    td.append(outer, document.createTextNode(fmt(p)));
    return td;
  }

  /** A small line of recent P(M1|H) values on a fixed 0..1 scale. */
  function sparkline(values) {
    const td = document.createElement("td");
    td.className = "left";
    const w = 110, h = 22;
    const svg = document.createElementNS("http://www.w3.org/2000/svg", "svg");
    svg.setAttribute("class", "spark");
    svg.setAttribute("width", w);
    svg.setAttribute("height", h);
    svg.setAttribute("viewBox", `0 0 ${w} ${h}`);
    if (values.length > 1) {
      const line = document.createElementNS(svg.namespaceURI, "polyline");
      const points = values.map((v, i) => `${(i * (w - 2)) / (values.length - 1) + 1},` +
        `${(1 - v) * (h - 2) + 1}`);
      line.setAttribute("points", points.join(" "));
      line.setAttribute("fill", "none");
      line.setAttribute("stroke", "#326edc");
      line.setAttribute("stroke-width", "1.5");
      svg.append(line);
    }
    td.append(svg);
    return td;
  }

  function lastAdvice(advice) {
    if (!advice) return cell("–", "left");
    const best = ACTIONS.reduce((a, b) => (advice.advice[b] > advice.advice[a] ? b : a));
    return cell(`step ${advice.step} at [${advice.state.join(", ")}]: ` +
      `${ARROWS[best]} ${best} ${Math.round(100 * advice.advice[best])}%`, "left");
  }

  function renderDomains(domains) {
    const body = $("domains").tBodies[0];
    if (!domains.length) {
      body.replaceChildren(emptyRow(9, "No domains."));
      return;
    }
    body.replaceChildren(...domains.map((d) => {
      const tr = document.createElement("tr");
      tr.dataset.domain = d.name;
      const walk = document.createElement("td");
      walk.className = "left";
      const a = document.createElement("a");
      a.href = `/walk?domain=${encodeURIComponent(d.name)}`;
      a.textContent = "walk it";
      walk.append(a);
      tr.append(cell(d.name, "left"), cell(`${d.rows}×${d.cols}`), cell(d.n_states),
                cell(d.trajectories), cell(d.sessions), cell(d.steps),
                cell(fmt(d.advice_per_100, 1)), cell(d.looking_lost), walk);
      return tr;
    }));
  }

  // The advising strategy; goal_aware sessions also list the goals still possible.
  function strategy(s) {
    const td = cell(s.strategy || "paper", "left");
    if (s.goals) {
      const open = s.goals.filter((g) => !g.ruled_out).length;
      td.textContent += ` (${open}/${s.goals.length} goals)`;
      td.title = s.goals.map((g) => `[${g.goal.join(", ")}]: ${g.ruled_out ? "ruled out" : g.p.toFixed(2)}`).join("\n");
    }
    return td;
  }

  function renderSessions(sessions, total, detail) {
    const body = $("sessions").tBodies[0];
    $("session-total").textContent = total > sessions.length
      ? `(${total} live; the ${sessions.length} most recently active shown)` : `(${total} live)`;
    if (!detail) {
      body.replaceChildren(emptyRow(13, refused
        ? `The key was refused (${refused}): enter the operator key to see live sessions.`
        : "Live sessions are shown with the operator key (above)."));
      return;
    }
    if (!sessions.length) {
      body.replaceChildren(emptyRow(13, "No live sessions. Walk the maze, or run python -m app simulate."));
      return;
    }
    body.replaceChildren(...sessions.map((s) => {
      const tr = document.createElement("tr");
      tr.dataset.sessionId = s.session_id;
      tr.append(cell(s.session_id, "left mono"), cell(s.domain, "left"),
                cell(s.agent_type || "–", "left"), strategy(s), cell(s.kappa), cell(s.steps),
                cell(`[${s.position.join(", ")}]`), bar(s.p_normal),
                sparkline(s.p_normal_history || []), cell(s.advice_count),
                cell(fmt(s.total_cost, 2)), cell(fmt(s.advice_per_100, 1)),
                lastAdvice(s.last_advice));
      return tr;
    }));
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

  async function poll() {
    try {
      const answer = await overview();
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

  poll();
  fetchJSON("/viewer").then((v) => showViewerLink($("viewer-link"), v)).catch(() => {});
})();
