// Top-down map of a session: its trajectory (GET /sessions/{id}/poses) and the hits of a
// search in that session (GET /search?session=...) drawn where they happened, as SVG.
// x grows to the right, y upwards (REP 103); one frame is drawn ("map" when the session has it).

const SVG = "http://www.w3.org/2000/svg";
const WIDTH = 480;
const HEIGHT = 320;
const PAD = 24;
const MAX_VERTICES = 4000; // a longer trajectory is thinned for drawing (every n-th pose)

function s(tag, attrs = {}, ...children) {
  const el = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "dataset") Object.assign(el.dataset, v);
    else el.setAttribute(k, String(v));
  }
  for (const c of children) el.append(c instanceof Node ? c : document.createTextNode(String(c)));
  return el;
}

// The trajectory to draw: frame "map" first, else the first one.
export function pickTrajectory(trajectories) {
  if (!trajectories.length) return null;
  return trajectories.find((t) => t.frame === "map") || trajectories[0];
}

// world (x, y) -> svg (px, py): one scale for both axes, y flipped, centred.
export function projection(points) {
  let [x0, x1, y0, y1] = [Infinity, -Infinity, Infinity, -Infinity];
  for (const [x, y] of points) {
    x0 = Math.min(x0, x); x1 = Math.max(x1, x);
    y0 = Math.min(y0, y); y1 = Math.max(y1, y);
  }
  const span = Math.max(x1 - x0, y1 - y0, 1e-6);
  const scale = Math.min((WIDTH - 2 * PAD) / Math.max(x1 - x0, span * 1e-3),
                         (HEIGHT - 2 * PAD) / Math.max(y1 - y0, span * 1e-3));
  const cx = (x0 + x1) / 2;
  const cy = (y0 + y1) / 2;
  const project = ([x, y]) => [WIDTH / 2 + (x - cx) * scale, HEIGHT / 2 - (y - cy) * scale];
  project.scale = scale;
  return project;
}

function niceLength(metres) {
  const p = 10 ** Math.floor(Math.log10(metres));
  for (const m of [5, 2, 1]) if (m * p <= metres) return m * p;
  return p;
}

// Draw the trajectory and the placed hits (of the trajectory's frame) into `svg`; returns
// {drawn, elsewhere}: hits drawn, and hits placed in another frame or not at all.
export function drawMap(svg, trajectory, hits, onHit) {
  svg.replaceChildren();
  svg.setAttribute("viewBox", `0 0 ${WIDTH} ${HEIGHT}`);
  const pos = trajectory.position;
  const onMap = hits.filter((hit) => hit.position && hit.frame === trajectory.frame);
  const project = projection([...pos, ...onMap.map((hit) => hit.position)]);
  const step = Math.max(1, Math.ceil(pos.length / MAX_VERTICES));
  const verts = pos.filter((_, i) => i % step === 0 || i === pos.length - 1).map(project);
  svg.append(
    s("rect", { class: "map-bg", x: 0, y: 0, width: WIDTH, height: HEIGHT }),
    s("polyline", {
      class: "trajectory",
      points: verts.map(([x, y]) => `${x.toFixed(2)},${y.toFixed(2)}`).join(" "),
      dataset: { poses: String(pos.length), frame: trajectory.frame },
    }),
  );
  const [sx, sy] = project(pos[0]);
  const [ex, ey] = project(pos[pos.length - 1]);
  svg.append(
    s("circle", { class: "map-start", cx: sx, cy: sy, r: 4 }, s("title", {}, "start")),
    s("rect", { class: "map-end", x: ex - 4, y: ey - 4, width: 8, height: 8 }, s("title", {}, "end")),
  );
  // scale bar, bottom left
  const metres = niceLength((WIDTH - 2 * PAD) / 4 / project.scale);
  const barPx = metres * project.scale;
  svg.append(
    s("line", { class: "map-scale", x1: PAD, y1: HEIGHT - 10, x2: PAD + barPx, y2: HEIGHT - 10 }),
    s("text", { class: "map-label", x: PAD, y: HEIGHT - 14 }, `${metres} m`),
    s("text", { class: "map-label", x: WIDTH - PAD, y: HEIGHT - 6, "text-anchor": "end" },
      `frame ${trajectory.frame} · x → · y ↑`),
  );
  // hits, the best drawn last (on top)
  onMap.forEach((hit, i) => { hit._rank = hits.indexOf(hit) + 1; });
  for (const hit of [...onMap].reverse()) {
    const [px, py] = project(hit.position);
    const label = `#${hit._rank} ${hit.sense}${hit.text ? `: ${hit.text}` : ""} (score ${hit.score.toFixed(2)}, t ${hit.t.toFixed(2)} s)`;
    const dot = s("circle", {
      class: hit._rank === 1 ? "map-hit best" : "map-hit",
      cx: px.toFixed(2), cy: py.toFixed(2), r: hit._rank === 1 ? 9 : 6, tabindex: 0,
      role: "button", "aria-label": label,
      dataset: { id: hit.id, rank: String(hit._rank), x: String(hit.position[0]), y: String(hit.position[1]) },
    }, s("title", {}, label));
    const open = () => onHit && onHit(hit.id);
    dot.addEventListener("click", open);
    dot.addEventListener("keydown", (e) => { if (e.key === "Enter" || e.key === " ") { e.preventDefault(); open(); } });
    svg.append(dot, s("text", { class: "map-rank", x: px + 10, y: py - 8 }, String(hit._rank)));
  }
  return { drawn: onMap.length, elsewhere: hits.length - onMap.length };
}
