// The walk page: a person walks a maze with the arrow keys; every move goes to the advisor over
// the session's websocket, and each decision that advises is drawn as arrows with probabilities.
// Beside the maze, always in view (the map scrolls and zooms in its own box): what the advisor
// believes of the walker as its strategy says it (GET /sessions/{id} with the session's token,
// read again after each decision), where its advice leads, the advice's worth against its price
// κ, P(M1|H) after each move, the map's destinations by name, and a legend. On a building of
// several floors (GET /domains/{name} has "floors") the map is the walker's floor, followed as
// it rides; cells are [floor, row, col], PageUp/PageDown (R/F) ride where a stair or lift is,
// and advice says "take the lift up" as it says "go east".
"use strict";

(() => {
  const { ACTIONS, MOVES, ARROWS, COLOURS, fetchJSON, fitCell, sizeCanvas, drawMaze, centre,
          drawArrow, goalIndex, goalLabel, destinationText, figureText, fmt } = MazeUI;
  const KEYS = {
    ArrowUp: "N", ArrowRight: "E", ArrowDown: "S", ArrowLeft: "W",
    w: "N", d: "E", s: "S", a: "W", W: "N", D: "E", S: "S", A: "W",
    PageUp: "U", PageDown: "D", r: "U", f: "D", R: "U", F: "D",
  };
  const RIDES = ["U", "D"];
  const RIDE_ARROWS = { U: "⇧", D: "⇩" };
  const WAYS = { N: "go north", E: "go east", S: "go south", W: "go west" };
  const STOP_FILL = "#7a4fc2"; // a stop of stairs or a lift
  const MIN_ADVICE_P = 0.03; // arrows below this probability are not drawn
  const ADVISED_FILL = "rgba(214, 69, 69, 0.35)"; // a dot where advice was given
  const $ = (id) => document.getElementById(id);
  const canvas = $("maze");
  const ctx = canvas.getContext("2d");

  const walk = {
    map: null, cell: 20, pos: null, path: [], session: null, socket: null, pending: 0,
    decision: null, advice: null, advisedCells: [], background: null, domain: null,
    history: [], // {step, p, advised} of every decision of this walk, oldest first
    beliefs: null, leadsTo: null, asking: false, askAgain: false,
    // a building: its floors (GET /domains' "floors"), the floor drawn, and each stop's rides
    // ("f,r,c" -> {U: [f, r, c] or null, D: ..., kind, name})
    floors: null, floor: 0, stops: new Map(),
  };
  const ZOOM = [2, 3, 4, 6, 8, 10, 12, 16, 20, 24, 32]; // cell sizes, CSS pixels
  // What each strategy's advice is, in plain words (GET /strategies: its entry says it).
  const NOTES = {};

  // The walls and floor drawn once per walk (a 256 x 256 map is 65,536 cells), then copied.
  function background() {
    if (!walk.background) {
      const off = document.createElement("canvas");
      off.width = canvas.width;
      off.height = canvas.height;
      const octx = off.getContext("2d");
      octx.setTransform(ctx.getTransform());
      canvas.dataset.labelPx = drawMaze(octx, walk.map, walk.cell, floorGoalNames());
      if (walk.floors) drawStops(octx);
      walk.background = off;
    }
    return walk.background;
  }

  function setStatus(text, isError = false) {
    const el = $("status");
    el.textContent = text;
    el.classList.toggle("error", isError);
  }

  function isFree(r, c) {
    const map = walk.map;
    return r >= 0 && r < map.length && c >= 0 && c < map[0].length && map[r][c] !== "#";
  }

  /** A cell's row and column (a building's cells are [floor, row, col]). */
  function rc(cell) {
    return walk.floors ? cell.slice(1) : cell;
  }

  /** Whether a cell is on the floor drawn. */
  function onFloor(cell) {
    return !walk.floors || cell[0] === walk.floor;
  }

  function sameCell(a, b) {
    return a.length === b.length && a.every((v, i) => v === b[i]);
  }

  // The same transitions as the service: a move into a wall or off the map stays put; U and D
  // ride to the next stop above or below where the cell is a stop, and stay put elsewhere.
  function stepLocal(pos, a) {
    if (RIDES.includes(a)) {
      const stop = walk.stops.get(pos.join(","));
      return stop && stop[a] ? stop[a] : pos.slice();
    }
    const [dr, dc] = MOVES[a];
    const [r0, c0] = rc(pos);
    const r = r0 + dr, c = c0 + dc;
    if (!isFree(r, c)) return pos.slice();
    return walk.floors ? [pos[0], r, c] : [r, c];
  }

  /** Each stop of the building's connections: where U and D lead from it. */
  function stopsOf(connections) {
    const stops = new Map();
    for (const conn of connections || []) {
      const sorted = [...conn.stops].sort((x, y) => x[0] - y[0]);
      sorted.forEach((cell, i) => stops.set(cell.join(","), {
        U: sorted[i + 1] || null, D: sorted[i - 1] || null, kind: conn.kind, name: conn.name,
      }));
    }
    return stops;
  }

  /** The destinations' labels on the floor drawn, in its row-major order (as drawMaze counts
   *  them): their names, else G and their index among the building's. */
  function floorGoalNames() {
    const domain = walk.domain;
    if (!walk.floors) return domain.goal_names;
    const names = [];
    domain.goals.forEach((cell, i) => {
      if (cell[0] === walk.floor) names.push((domain.goal_names && domain.goal_names[i]) || `G${i}`);
    });
    return names;
  }

  /** The index of the building's (or map's) destination at a cell, or -1. */
  function goalAt(cell) {
    if (!walk.floors) return goalIndex(walk.map, cell);
    return walk.domain.goals.findIndex((g) => sameCell(g, cell));
  }

  /** The stops of the floor drawn: a violet mark with ⇧, ⇩ or ⇅ (where it leads). */
  function drawStops(g) {
    const cell = walk.cell;
    g.font = `bold ${Math.max(9, Math.floor(cell * 0.6))}px system-ui, sans-serif`;
    g.textAlign = "center";
    g.textBaseline = "middle";
    for (const [key, stop] of walk.stops) {
      const at = key.split(",").map(Number);
      if (at[0] !== walk.floor) continue;
      const [x, y] = centre(at.slice(1), cell);
      g.fillStyle = STOP_FILL;
      g.fillRect(x - cell / 2 + 1, y - cell / 2 + 1, cell - 2, cell - 2);
      g.fillStyle = "#fff";
      g.fillText(stop.U && stop.D ? "⇅" : stop.U ? "⇧" : "⇩", x, y);
    }
  }

  /** The floor the map shows: the walker's (drawn again when it changes). */
  function showFloor(f) {
    if (!walk.floors) return;
    const floor = walk.floors[f];
    if (walk.floor !== f || walk.map !== floor.map) {
      walk.floor = f;
      walk.map = floor.map;
      walk.background = null;
    }
    $("floor").textContent = `${floor.name} (ordinal ${floor.ordinal})`;
    document.body.dataset.floor = f;
    const stop = walk.pos ? walk.stops.get(walk.pos.join(",")) : null;
    const note = $("ride-note");
    note.hidden = !stop;
    if (stop) {
      const ways = [stop.U && "up (PageUp or R)", stop.D && "down (PageDown or F)"].filter(Boolean);
      note.textContent = `Here: ${stop.name} (${stop.kind}), ${ways.join(" or ")}.`;
    }
  }

  /** The most advised way in words: "go east", "take the lift up" (none when no way is
   *  advised clearly more than the others). */
  function adviceWords(advice, state) {
    const ways = Object.keys(advice).sort((x, y) => advice[y] - advice[x]);
    const best = ways[0];
    if (advice[best] - advice[ways[1]] < 0.01) return "No way stands out here";
    if (!RIDES.includes(best)) return `${capitalised(WAYS[best])} (${Math.round(100 * advice[best])}%)`;
    const stop = walk.stops.get(state.join(","));
    const what = stop ? `the ${stop.kind === "lift" ? "lift" : stop.kind}` : "the stairs or lift";
    const way = best === "U" ? "up" : "down";
    return `Take ${what} ${way} (${Math.round(100 * advice[best])}%)`;
  }

  function draw() {
    if (!walk.map) return;
    const cell = walk.cell;
    ctx.save();
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.drawImage(background(), 0, 0);
    ctx.restore();
    ctx.fillStyle = ADVISED_FILL;
    for (const at of walk.advisedCells) {
      if (!onFloor(at)) continue;
      const [x, y] = centre(rc(at), cell);
      ctx.beginPath();
      ctx.arc(x, y, cell * 0.16, 0, 2 * Math.PI);
      ctx.fill();
    }
    if (walk.path.length > 1) {
      ctx.strokeStyle = COLOURS.path;
      ctx.lineWidth = Math.max(2, cell * 0.18);
      ctx.lineJoin = "round";
      ctx.beginPath();
      let drawing = false; // the path's stretches on the floor drawn
      for (const at of walk.path) {
        if (!onFloor(at)) {
          drawing = false;
          continue;
        }
        const [x, y] = centre(rc(at), cell);
        if (drawing) ctx.lineTo(x, y); else ctx.moveTo(x, y);
        drawing = true;
      }
      ctx.stroke();
    }
    if (walk.pos) {
      const [x, y] = centre(rc(walk.pos), cell);
      ctx.fillStyle = COLOURS.walker;
      ctx.beginPath();
      ctx.arc(x, y, Math.max(4, cell * 0.32), 0, 2 * Math.PI); // seen on a small cell too
      ctx.fill();
      if (walk.advice && walk.pending === 0) drawAdvice(x, y, walk.advice);
    }
  }

  /** Scroll the map's box so that the walker and a few cells around it are in view. */
  function keepInView() {
    if (!walk.pos) return;
    const board = $("board");
    const [x, y] = centre(rc(walk.pos), walk.cell);
    const left = x + canvas.offsetLeft, top = y + canvas.offsetTop; // the box is positioned
    const margin = Math.min(4 * walk.cell + 24, board.clientWidth / 3, board.clientHeight / 3);
    if (left - margin < board.scrollLeft) board.scrollLeft = left - margin;
    else if (left + margin > board.scrollLeft + board.clientWidth) board.scrollLeft = left + margin - board.clientWidth;
    if (top - margin < board.scrollTop) board.scrollTop = top - margin;
    else if (top + margin > board.scrollTop + board.clientHeight) board.scrollTop = top + margin - board.clientHeight;
  }

  /** Draw the map at cell size ``cell`` (CSS pixels), the walker kept in view. */
  function zoomTo(cell) {
    if (!walk.map) return;
    walk.cell = cell;
    sizeCanvas(canvas, walk.map.length, walk.map[0].length, cell);
    walk.background = null;
    canvas.dataset.cell = cell;
    draw();
    keepInView();
  }

  /** The largest cell at which the map fits its box (``least``: the smallest allowed). */
  function fitted(least) {
    const board = $("board");
    const pad = 2 * 10; // the box's padding
    return fitCell(walk.map.length, walk.map[0].length, board.clientWidth - pad,
                   board.clientHeight - pad, least, 32);
  }

  /** One zoom step larger (+1) or smaller (-1) than the cell size now. */
  function zoomBy(step) {
    if (!walk.map) return;
    const next = step > 0 ? ZOOM.find((c) => c > walk.cell)
      : [...ZOOM].reverse().find((c) => c < walk.cell);
    zoomTo(next === undefined ? walk.cell : next);
  }

  function drawAdvice(x, y, advice) {
    const cell = walk.cell;
    ctx.font = `bold ${Math.max(10, Math.floor(cell * 0.55))}px system-ui, sans-serif`;
    ctx.textAlign = "center"; // each label centred on its tag
    ctx.textBaseline = "middle";
    for (const a of ACTIONS) {
      const p = advice[a];
      if (p < MIN_ADVICE_P) continue;
      const [x2, y2] = drawArrow(ctx, x, y, a, cell * (0.45 + 2.2 * p), COLOURS.advice,
                                 Math.max(2, cell * 0.14));
      const [dr, dc] = MOVES[a];
      const label = `${Math.round(100 * p)}%`;
      const tx = x2 + dc * cell * 0.9, ty = y2 + dr * cell * 0.55;
      const w = ctx.measureText(label).width + 6;
      ctx.fillStyle = "rgba(255, 255, 255, 0.9)";
      ctx.fillRect(tx - w / 2, ty - cell * 0.35, w, cell * 0.7);
      ctx.fillStyle = COLOURS.advice;
      ctx.fillText(label, tx, ty);
    }
    const stop = walk.floors ? walk.stops.get(walk.pos.join(",")) : null;
    RIDES.forEach((a, i) => { // up and down where there is a ride: a tag clear of the arrows
      const p = advice[a];
      if (!stop || !stop[a] || p < MIN_ADVICE_P) return;
      const label = `${RIDE_ARROWS[a]} ${Math.round(100 * p)}%`;
      const w = ctx.measureText(label).width + 6;
      const [width, height] = [walk.map[0].length * cell, walk.map.length * cell];
      const tx = Math.min(width - w / 2, Math.max(w / 2, x - cell * 2));
      const ty = Math.min(height - cell * 0.35, Math.max(cell * 0.35, y + (i ? 1 : -1) * cell * 1.3));
      ctx.fillStyle = STOP_FILL;
      ctx.fillRect(tx - w / 2, ty - cell * 0.35, w, cell * 0.7);
      ctx.fillStyle = "#fff";
      ctx.fillText(label, tx, ty);
    });
  }

  /** P(M1|H) after each decision of this walk, 0 to 1 upwards, a dotted line at 0.5, the
   *  decisions that advised marked in red. */
  function drawChart() {
    const chart = $("p-chart");
    const w = 300, h = 120, left = 26, right = 6, top = 6, bottom = 18;
    const ratio = window.devicePixelRatio || 1;
    if (chart.width !== Math.round(w * ratio)) {
      chart.width = Math.round(w * ratio);
      chart.height = Math.round(h * ratio);
      chart.style.width = `${w}px`;
      chart.style.height = `${h}px`;
    }
    const g = chart.getContext("2d");
    g.setTransform(ratio, 0, 0, ratio, 0, 0);
    g.clearRect(0, 0, w, h);
    const points = walk.history;
    const first = points.length ? points[0].step : 0;
    const span = Math.max(10, points.length ? points[points.length - 1].step - first : 0);
    const x = (step) => left + ((step - first) / span) * (w - left - right);
    const y = (p) => top + (1 - p) * (h - top - bottom);
    g.font = "10px system-ui, sans-serif";
    g.fillStyle = COLOURS.text;
    g.textAlign = "right";
    g.textBaseline = "middle";
    for (const p of [0, 0.5, 1]) g.fillText(String(p), left - 4, y(p));
    g.textAlign = "center";
    g.textBaseline = "top";
    g.fillText(`step ${first}`, left + 14, h - bottom + 4);
    g.fillText(`${first + span}`, w - right - 8, h - bottom + 4);
    g.strokeStyle = "#d9dce3";
    g.lineWidth = 1;
    g.strokeRect(left, top, w - left - right, h - top - bottom);
    g.setLineDash([2, 3]);
    g.beginPath();
    g.moveTo(left, y(0.5));
    g.lineTo(w - right, y(0.5));
    g.stroke();
    g.setLineDash([]);
    if (points.length) {
      g.strokeStyle = COLOURS.walker;
      g.lineWidth = 1.5;
      g.beginPath();
      points.forEach((pt, i) => (i ? g.lineTo(x(pt.step), y(pt.p)) : g.moveTo(x(pt.step), y(pt.p))));
      g.stroke();
      g.fillStyle = COLOURS.advice;
      for (const pt of points) {
        if (!pt.advised) continue;
        g.beginPath();
        g.arc(x(pt.step), y(pt.p), 2.2, 0, 2 * Math.PI);
        g.fill();
      }
    }
    chart.dataset.points = points.length;
    chart.dataset.last = points.length ? points[points.length - 1].p : "";
  }

  function remember(d) {
    const h = walk.history;
    while (h.length && h[h.length - 1].step >= d.step) h.pop(); // a decision given again
    h.push({ step: d.step, p: d.p_normal, advised: Boolean(d.advise) });
  }

  function showDecision(d) {
    walk.decision = d;
    $("steps").textContent = d.step;
    $("position").textContent = `[${d.state.join(", ")}]`;
    const kappa = walk.session ? walk.session.kappa : NaN;
    $("kl").textContent = `${fmt(d.kl)} nats`;
    $("kl").title = "KL[θ‖P(A|s,H)]";
    $("kl-rule").textContent = `worth ${fmt(d.kl)} ${d.advise ? "≥" : "<"} price ${kappa} → ` +
      `${d.advise ? "advised" : "not advised"} (KL ${d.advise ? "≥" : "<"} κ)`;
    $("kl-rule").classList.toggle("advised", Boolean(d.advise));
    remember(d);
    drawChart();
    $("advice-count").textContent = d.cost.advice_count;
    $("cost").textContent = fmt(d.cost.total, 2);
    const g = goalAt(d.state);
    $("goal-note").textContent = g >= 0 ? `You are at ${goalLabel(g, walk.domain.goal_names)}.` : "";
    if (d.advise && d.leads_to) showLeadsTo(d.leads_to);
    document.body.dataset.goal = g >= 0 ? `G${g}` : "";
    document.body.dataset.position = JSON.stringify(d.state);
    document.body.dataset.step = d.step;
    const panel = $("advice");
    if (d.advise && d.advice) {
      walk.advice = d.advice;
      walk.advisedCells.push(d.state);
      $("advice-step").textContent = d.step;
      $("advice-words").textContent = adviceWords(d.advice, d.state);
      document.body.dataset.adviceWords = $("advice-words").textContent;
      const list = $("advice-list");
      list.replaceChildren(...Object.keys(d.advice).map((a) => {
        const li = document.createElement("li");
        li.dataset.action = a;
        li.innerHTML = `<span class="arrow"></span><span class="p"></span>` +
          `<span class="bar"><span></span></span>`;
        li.querySelector(".arrow").textContent = `${ARROWS[a] || RIDE_ARROWS[a]} ${a}`;
        li.querySelector(".p").textContent = `${(100 * d.advice[a]).toFixed(1)}%`;
        li.querySelector(".bar > span").style.width = `${(100 * d.advice[a]).toFixed(1)}%`;
        return li;
      }));
      panel.hidden = false;
    } else {
      walk.advice = null;
      panel.hidden = true;
    }
    document.body.dataset.advice = walk.advice ? JSON.stringify(walk.advice) : "";
  }

  /** Where the advice leads, named: in the figures and on the destinations' list. */
  function showLeadsTo(to) {
    walk.leadsTo = to;
    const p = $("leads-to");
    p.hidden = !to;
    p.textContent = to ? `Advice leads to ${destinationText(to)} [${to.cell.join(", ")}]` : "";
    document.body.dataset.leadsTo = to ? String(to.goal) : "";
    for (const li of $("destinations").children) {
      li.classList.toggle("target", Boolean(to) && Number(li.dataset.goal) === to.goal);
    }
  }

  /** What the advisor believes, as the session's strategy says it: each figure in plain words
   *  with its symbol, coloured by the strategy's tone, the one that says most in bold. */
  function showBeliefs(b, step) {
    walk.beliefs = b;
    const list = $("beliefs");
    list.replaceChildren(...b.figures.flatMap((f, i) => {
      const dt = document.createElement("dt");
      dt.textContent = f.name;
      const dd = document.createElement("dd");
      dd.textContent = `${Math.round(100 * f.p)}% (${f.symbol})`;
      dd.title = figureText(f);
      for (const el of [dt, dd]) {
        el.classList.add(`tone-${f.tone}`);
        el.classList.toggle("headline", i === b.headline);
        el.dataset.tone = f.tone;
      }
      return [dt, dd];
    }));
    const normal = b.figures.find((f) => f.symbol === "P(M1|H)");
    $("p-chart-name").textContent = normal ? capitalised(normal.name) : "Knows the way";
    showLeadsTo(b.leads_to);
    document.body.dataset.beliefsStep = step;
  }

  function capitalised(text) {
    return text.charAt(0).toUpperCase() + text.slice(1);
  }

  /** Ask the session what its advisor believes now (one request at a time; asked again once
   *  it answers if a decision came meanwhile). */
  async function askBeliefs() {
    if (walk.asking) {
      walk.askAgain = true;
      return;
    }
    const session = walk.session;
    if (!session) return;
    walk.asking = true;
    try {
      const seen = await fetchJSON(`/sessions/${encodeURIComponent(session.session_id)}`, {
        headers: { Authorization: `Bearer ${session.token}` },
      });
      if (walk.session === session && seen.beliefs) showBeliefs(seen.beliefs, seen.steps);
    } catch (err) {
      if (walk.session === session) setStatus(`Could not read the advisor's beliefs: ${err.message}`, true);
    } finally {
      walk.asking = false;
      if (walk.askAgain) {
        walk.askAgain = false;
        askBeliefs();
      }
    }
  }

  /** The map's destinations, named where the map names them, with their cells. */
  function listDestinations(domain) {
    $("destinations").replaceChildren(...domain.goals.map((cell, i) => {
      const li = document.createElement("li");
      li.dataset.goal = i;
      const name = domain.goal_names ? domain.goal_names[i] : null;
      li.textContent = `${name ? `${name} · ` : ""}G${i} [${cell.join(", ")}]`;
      return li;
    }));
  }

  function onMessage(event) {
    let data;
    try {
      data = JSON.parse(event.data);
    } catch (err) {
      setStatus(`Unreadable message from the service: ${err}`, true);
      return;
    }
    if (data && !Array.isArray(data) && data.detail) {
      setStatus(`The service refused a move: ${data.detail}`, true);
      walk.pending = 0;
      if (walk.decision) walk.pos = walk.decision.state; // back to where the service has us
      if (walk.floors) showFloor(walk.pos[0]);
      draw();
      return;
    }
    for (const d of Array.isArray(data) ? data : [data]) {
      walk.pending = Math.max(0, walk.pending - 1);
      document.body.dataset.pending = walk.pending;
      showDecision(d);
      if (walk.pending === 0 && !sameCell(d.state, walk.pos)) {
        walk.pos = d.state; // the service is the truth
        walk.path.push(d.state);
      }
    }
    if (walk.floors) showFloor(walk.pos[0]);
    draw();
    keepInView();
    askBeliefs();
  }

  function move(a) {
    const socket = walk.socket;
    if (!socket || socket.readyState !== WebSocket.OPEN) return;
    const from = walk.pos;
    walk.pos = stepLocal(from, a);
    walk.path.push(walk.pos);
    if (walk.floors) showFloor(walk.pos[0]);
    walk.pending += 1;
    document.body.dataset.pending = walk.pending;
    socket.send(JSON.stringify({ state: from, action: a }));
    draw();
    keepInView();
  }

  function openSocket(created) {
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    const url = `${scheme}://${location.host}/sessions/${encodeURIComponent(created.session_id)}` +
      "/stream";
    // the token travels as a subprotocol, not in the URL (which logs and proxies keep)
    const socket = new WebSocket(url, ["advisor", `token.${created.token}`]);
    walk.socket = socket;
    socket.addEventListener("open", () => {
      if (walk.socket === socket) setStatus("Connected: walk with the arrow keys.");
    });
    socket.addEventListener("message", (e) => { if (walk.socket === socket) onMessage(e); });
    socket.addEventListener("close", (e) => {
      if (walk.socket !== socket) return;
      walk.socket = null;
      setStatus(`Disconnected (${e.code}${e.reason ? ": " + e.reason : ""}). Press “New walk”.`,
                e.code !== 1000);
    });
  }

  async function newWalk() {
    const name = $("domain").value;
    if (!name) return;
    if (walk.socket) {
      const old = walk.socket;
      walk.socket = null;
      old.close(1000, "new walk");
    }
    setStatus("Starting a session…");
    try {
      const domain = await fetchJSON(`/domains/${encodeURIComponent(name)}`);
      const kappa = Number($("kappa").value);
      const strategy = $("strategy").value;
      const body = Number.isFinite(kappa) && kappa >= 0 ? { kappa, strategy } : { strategy };
      const created = await fetchJSON(`/domains/${encodeURIComponent(name)}/sessions`, {
        method: "POST", body: JSON.stringify(body),
      });
      const floors = domain.floors || null;
      Object.assign(walk, {
        map: domain.map, pos: created.decision.state, path: [created.decision.state],
        session: created, pending: 0, advice: null, advisedCells: [], background: null,
        history: [], domain, beliefs: null, leadsTo: null, floors, floor: -1,
        stops: stopsOf(domain.connections),
      });
      for (const el of document.querySelectorAll(".floors-only, #floor-keys")) el.hidden = !floors;
      if (floors) showFloor(walk.pos[0]);
      $("beliefs").replaceChildren();
      listDestinations(domain);
      showLeadsTo(null);
      zoomTo(fitted(6));
      $("advice-note").textContent = NOTES[created.strategy] || "";
      $("session").textContent = `Session ${created.session_id} · ${created.strategy} · ` +
        `κ = ${created.kappa} · window ${created.window}`;
      document.body.dataset.pending = 0;
      document.body.dataset.sessionId = created.session_id;
      showDecision(created.decision);
      draw();
      askBeliefs();
      openSocket(created);
      canvas.focus();
    } catch (err) {
      setStatus(`Could not start a walk: ${err.message}`, true);
    }
  }

  /** The strategies the service offers (GET /strategies), the page's ?strategy= picked. */
  async function loadStrategies() {
    const listed = await fetchJSON("/strategies");
    const options = listed.map((s) => {
      NOTES[s.name] = s.advice;
      const option = new Option(s.name, s.name);
      option.title = s.summary;
      return option;
    });
    $("strategy").replaceChildren(...options);
    const wanted = new URLSearchParams(location.search).get("strategy");
    const names = listed.map((s) => s.name);
    $("strategy").value = names.includes(wanted) ? wanted : names[0];
  }

  async function loadDomains() {
    const select = $("domain");
    const listed = await fetchJSON("/domains");
    const domains = Array.isArray(listed) ? listed : listed.domains;
    const query = new URLSearchParams(location.search);
    const wanted = query.get("domain");
    select.replaceChildren(...domains.map((d) => new Option(d.name, d.name)));
    const names = domains.map((d) => d.name);
    select.value = names.includes(wanted) ? wanted : (names.includes("default") ? "default" : names[0]);
  }

  /** The legend's swatches, drawn with the maze's own colours and shapes. */
  function drawLegend() {
    const size = 22;
    const ratio = window.devicePixelRatio || 1;
    const shapes = {
      wall: (g) => { g.fillStyle = COLOURS.wall; g.fillRect(2, 2, size - 4, size - 4); },
      start: (g) => drawMaze(g, ["S"], size),
      goal: (g) => drawMaze(g, ["G"], size),
      walker: (g) => {
        g.fillStyle = COLOURS.walker;
        g.beginPath();
        g.arc(size / 2, size / 2, size * 0.32, 0, 2 * Math.PI);
        g.fill();
      },
      path: (g) => {
        g.strokeStyle = COLOURS.path;
        g.lineWidth = size * 0.18;
        g.lineCap = "round";
        g.beginPath();
        g.moveTo(3, size - 6);
        g.lineTo(size - 3, 6);
        g.stroke();
      },
      advised: (g) => {
        g.fillStyle = ADVISED_FILL;
        g.beginPath();
        g.arc(size / 2, size / 2, size * 0.16, 0, 2 * Math.PI);
        g.fill();
      },
      advice: (g) => drawArrow(g, 3, size / 2, "E", size - 5, COLOURS.advice, 2.5),
      stop: (g) => {
        g.fillStyle = STOP_FILL;
        g.fillRect(2, 2, size - 4, size - 4);
        g.fillStyle = "#fff";
        g.font = `bold ${size * 0.6}px system-ui, sans-serif`;
        g.textAlign = "center";
        g.textBaseline = "middle";
        g.fillText("⇅", size / 2, size / 2);
      },
    };
    for (const li of document.querySelectorAll("#maze-legend li")) {
      const swatch = document.createElement("canvas");
      swatch.className = "swatch";
      swatch.width = size * ratio;
      swatch.height = size * ratio;
      swatch.style.width = `${size}px`;
      swatch.style.height = `${size}px`;
      const g = swatch.getContext("2d");
      g.setTransform(ratio, 0, 0, ratio, 0, 0);
      g.fillStyle = COLOURS.floor;
      g.fillRect(0, 0, size, size);
      shapes[li.dataset.item](g);
      li.prepend(swatch);
    }
  }

  document.addEventListener("keydown", (e) => {
    const a = KEYS[e.key];
    if (!a || e.target.closest("input, select, textarea")) return;
    if (RIDES.includes(a) && !walk.floors) return; // one floor: nothing to ride
    e.preventDefault();
    move(a);
  });
  drawLegend();
  drawChart();
  $("restart").addEventListener("click", newWalk);
  $("zoom-in").addEventListener("click", () => zoomBy(1));
  $("zoom-out").addEventListener("click", () => zoomBy(-1));
  $("zoom-fit").addEventListener("click", () => walk.map && zoomTo(fitted(2)));
  $("domain").addEventListener("change", newWalk);
  $("strategy").addEventListener("change", newWalk);

  Promise.all([loadStrategies(), loadDomains()])
    .then(newWalk)
    .catch((err) => setStatus(`Could not load the mazes: ${err.message}`, true));
  MazeUI.watchViewerLink($("viewer-link"));
})();
