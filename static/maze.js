// Helpers shared by the dashboard and the walk page: JSON fetches, the viewer link, and
// drawing a maze with arrows on a 2D canvas. Plain browser JavaScript, no dependencies.
"use strict";

const MazeUI = (() => {
  const ACTIONS = ["N", "E", "S", "W"];
  const MOVES = { N: [-1, 0], E: [0, 1], S: [1, 0], W: [0, -1] };
  const ARROWS = { N: "↑", E: "→", S: "↓", W: "←" };
  const COLOURS = {
    floor: "#f4f2ec", wall: "#343d52", start: "#2ea043", goal: "#e6a817",
    path: "rgba(50, 110, 220, 0.55)", walker: "#326edc", advice: "#d64545", text: "#1f2430",
  };

  /** GET or POST JSON; throws an Error carrying the service's "detail" on a non-2xx answer. */
  async function fetchJSON(url, options = {}) {
    const response = await fetch(url, {
      ...options,
      headers: { "Content-Type": "application/json", ...(options.headers || {}) },
    });
    const body = await response.json().catch(() => null);
    if (!response.ok) {
      const detail = body && body.detail ? body.detail : response.statusText;
      throw new Error(`${response.status}: ${typeof detail === "string" ? detail : JSON.stringify(detail)}`);
    }
    return body;
  }

  /** Point a link at the viser viewer: same host, the viewer's port; hide it when there is
   *  none or it is not running (GET /viewer says). */
  function showViewerLink(link, viewer) {
    if (!link) return;
    if (!viewer || !viewer.enabled || !viewer.running || !viewer.port) {
      link.hidden = true;
      return;
    }
    link.href = `${location.protocol}//${location.hostname}:${viewer.port}/`;
    link.hidden = false;
  }

  /** Keep the viewer link in step with GET /viewer: now, then every few seconds (a viewer
   *  that dies, or starts late, shows so). An unanswered check hides it. */
  function watchViewerLink(link, everyMs = 5000) {
    if (!link) return;
    const check = () => fetchJSON("/viewer")
      .then((v) => showViewerLink(link, v))
      .catch(() => showViewerLink(link, null));
    check();
    setInterval(check, everyMs);
  }

  /** Cell size in CSS pixels so that a rows x cols map fits in maxSize. */
  function fitCanvas(canvas, rows, cols, maxSize) {
    const cell = Math.max(6, Math.floor(Math.min(maxSize / cols, maxSize / rows)));
    const ratio = window.devicePixelRatio || 1;
    canvas.style.width = `${cols * cell}px`;
    canvas.style.height = `${rows * cell}px`;
    canvas.width = Math.round(cols * cell * ratio);
    canvas.height = Math.round(rows * cell * ratio);
    const ctx = canvas.getContext("2d");
    ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
    return cell;
  }

  /** Walls, floor, start and goals (labelled G0, G1, ... in row-major order). */
  function drawMaze(ctx, map, cell) {
    const rows = map.length, cols = map[0].length;
    ctx.fillStyle = COLOURS.floor;
    ctx.fillRect(0, 0, cols * cell, rows * cell);
    let goal = 0;
    ctx.font = `${Math.max(8, Math.floor(cell * 0.45))}px system-ui, sans-serif`;
    ctx.textAlign = "center";
    ctx.textBaseline = "middle";
    for (let r = 0; r < rows; r++) {
      for (let c = 0; c < cols; c++) {
        const ch = map[r][c];
        if (ch === "#") {
          ctx.fillStyle = COLOURS.wall;
          ctx.fillRect(c * cell, r * cell, cell, cell);
        } else if (ch === "S" || ch === "G") {
          ctx.fillStyle = ch === "S" ? COLOURS.start : COLOURS.goal;
          ctx.fillRect(c * cell + 1, r * cell + 1, cell - 2, cell - 2);
          ctx.fillStyle = COLOURS.text;
          ctx.fillText(ch === "S" ? "S" : `G${goal++}`, (c + 0.5) * cell, (r + 0.5) * cell);
        }
      }
    }
  }

  function centre(cellRC, cell) {
    return [(cellRC[1] + 0.5) * cell, (cellRC[0] + 0.5) * cell];
  }

  /** An arrow from (x, y) of the given length (pixels) towards action a. */
  function drawArrow(ctx, x, y, a, length, colour, width) {
    const [dr, dc] = MOVES[a];
    const x2 = x + dc * length, y2 = y + dr * length;
    const head = Math.min(length * 0.5, width * 3.2);
    ctx.strokeStyle = colour;
    ctx.fillStyle = colour;
    ctx.lineWidth = width;
    ctx.lineCap = "round";
    ctx.beginPath();
    ctx.moveTo(x, y);
    ctx.lineTo(x2 - dc * head * 0.6, y2 - dr * head * 0.6);
    ctx.stroke();
    ctx.beginPath();
    ctx.moveTo(x2, y2);
    ctx.lineTo(x2 - dc * head - dr * head * 0.6, y2 - dr * head - dc * head * 0.6);
    ctx.lineTo(x2 - dc * head + dr * head * 0.6, y2 - dr * head + dc * head * 0.6);
    ctx.closePath();
    ctx.fill();
    return [x2, y2];
  }

  /** Index of the goal at a cell (row-major numbering, as drawn), or -1. */
  function goalIndex(map, cellRC) {
    let index = 0;
    for (let r = 0; r < map.length; r++) {
      for (let c = 0; c < map[r].length; c++) {
        if (map[r][c] !== "G") continue;
        if (r === cellRC[0] && c === cellRC[1]) return index;
        index++;
      }
    }
    return -1;
  }

  function fmt(x, digits = 3) {
    return Number.isFinite(x) ? x.toFixed(digits) : "–";
  }

  return {
    ACTIONS, MOVES, ARROWS, COLOURS, fetchJSON, showViewerLink, watchViewerLink, fitCanvas,
    drawMaze, centre, drawArrow, goalIndex, fmt,
  };
})();
