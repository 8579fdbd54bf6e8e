// Helpers shared by the dashboard and the walk page: JSON fetches, the viewer link, drawing a
// maze with arrows on a 2D canvas, and how both pages word what the advisor believes (plain
// words first, the paper's symbol second, the strategy's tone). Plain browser JavaScript, no
// dependencies.
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

  /** The largest cell size (CSS pixels, within [least, most]) at which a rows x cols map fits
   *  a width x height box. */
  function fitCell(rows, cols, width, height, least = 6, most = 32) {
    return Math.min(most, Math.max(least, Math.floor(Math.min(width / cols, height / rows))));
  }

  /** Size a canvas for a rows x cols map of the given cell size (CSS pixels). */
  function sizeCanvas(canvas, rows, cols, cell) {
    const ratio = window.devicePixelRatio || 1;
    canvas.style.width = `${cols * cell}px`;
    canvas.style.height = `${rows * cell}px`;
    canvas.width = Math.round(cols * cell * ratio);
    canvas.height = Math.round(rows * cell * ratio);
    const ctx = canvas.getContext("2d");
    ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
    return cell;
  }

  /** The smallest font of a label on the map (CSS pixels), however small its cells. */
  const LABEL_MIN_PX = 11;

  /** Walls, floor, start and goals; then the labels, S and each goal's name (G0, G1, ... in
   *  row-major order where the map names it not: ``names``, in that order), drawn over the
   *  cells at a readable size however small they are. Returns the smallest label's font size
   *  (CSS pixels). */
  function drawMaze(ctx, map, cell, names = null) {
    const rows = map.length, cols = map[0].length;
    ctx.fillStyle = COLOURS.floor;
    ctx.fillRect(0, 0, cols * cell, rows * cell);
    const labels = [];
    let goal = 0;
    for (let r = 0; r < rows; r++) {
      for (let c = 0; c < cols; c++) {
        const ch = map[r][c];
        if (ch === "#") {
          ctx.fillStyle = COLOURS.wall;
          ctx.fillRect(c * cell, r * cell, cell, cell);
        } else if (ch === "S" || ch === "G") {
          ctx.fillStyle = ch === "S" ? COLOURS.start : COLOURS.goal;
          const inset = cell > 4 ? 1 : 0;
          ctx.fillRect(c * cell + inset, r * cell + inset, cell - 2 * inset, cell - 2 * inset);
          labels.push({ text: ch === "S" ? "S" : goalLabel(goal++, names), r, c });
        }
      }
    }
    let smallest = Infinity;
    for (const label of labels) smallest = Math.min(smallest, drawLabel(ctx, label.text, label.r, label.c, cell));
    return smallest; // the smallest label's font, CSS pixels
  }

  /** A label centred on a cell: in the cell where it fits, else on a pale tag of at least
   *  LABEL_MIN_PX pixels. */
  function drawLabel(ctx, text, r, c, cell) {
    const size = Math.max(LABEL_MIN_PX, Math.floor(cell * 0.45));
    ctx.font = `${size}px system-ui, sans-serif`;
    ctx.textAlign = "center";
    ctx.textBaseline = "middle";
    const x = (c + 0.5) * cell, y = (r + 0.5) * cell;
    const w = ctx.measureText(text).width;
    if (w > cell - 2 || size > cell - 2) {
      ctx.fillStyle = "rgba(255, 255, 255, 0.85)";
      ctx.fillRect(x - w / 2 - 3, y - size / 2 - 2, w + 6, size + 4);
    }
    ctx.fillStyle = COLOURS.text;
    ctx.fillText(text, x, y);
    return size;
  }

  /** How a goal is named on the pages: its name (GET /domains' goal_names), else G<index>. */
  function goalLabel(index, names) {
    const name = names && names[index];
    return name || `G${index}`;
  }

  /** A destination of an answer ({goal, cell, name}) in words: "Exit (G1)", or "G1". */
  function destinationText(d) {
    return d.name ? `${d.name} (G${d.goal})` : `G${d.goal}`;
  }

  /** A figure of the advisor's beliefs, plain words first: "looks lost: 97% (P(M2|H))". */
  function figureText(f) {
    return `${f.name}: ${Math.round(100 * f.p)}% (${f.symbol})`;
  }

  /** A bar as long as p (0..1), coloured by the strategy's tone (good, neutral, bad). */
  function barOf(p, tone) {
    const outer = document.createElement("span");
    outer.className = `bar tone-${tone}`;
    const inner = document.createElement("span");
    inner.style.width = `${Math.round(100 * Math.min(1, Math.max(0, p)))}%`;
    outer.append(inner);
    return outer;
  }

  /** Every figure and where the advice leads, one line each (a tooltip). */
  function beliefsText(b) {
    const lines = b.figures.map(figureText);
    if (b.leads_to) lines.push(`advice leads to ${destinationText(b.leads_to)}`);
    return lines.join("\n");
  }

  /** A control this key may not use: disabled, saying why (in its tooltip). */
  function refuse(control, why) {
    control.disabled = true;
    control.title = why;
    control.setAttribute("aria-disabled", "true");
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
    ACTIONS, MOVES, ARROWS, COLOURS, LABEL_MIN_PX, fetchJSON, showViewerLink, watchViewerLink,
    fitCell, sizeCanvas, drawMaze, centre, drawArrow, goalIndex, goalLabel, destinationText,
    figureText, barOf, beliefsText, refuse, fmt,
  };
})();
