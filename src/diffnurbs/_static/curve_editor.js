// The curve editor's view: draws what the kernel computed and sends the user's edits back.
// The kernel evaluates every curve (one source of truth); the browser only moves control
// points, knots and weights, and redraws the control polygon at once while it waits.
const SVG = "http://www.w3.org/2000/svg";
const STRIP = 46; // knot strip: knots and the construction parameter
const PANEL = 110; // basis functions
const PAD = 14;
// Edits sent ahead of the drawings: the round trip through Jupyter is several times the
// kernel's work per edit, so a few requests in flight keep it busy without a backlog.
const MAX_INFLIGHT = 3;
const MEASURED = 1000;
const COLORS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
  "#7f7f7f", "#bcbd22", "#17becf"];

function node(tag, attrs = {}, parent = null) {
  const element = document.createElementNS(SVG, tag);
  for (const [key, value] of Object.entries(attrs)) element.setAttribute(key, value);
  if (parent) parent.appendChild(element);
  return element;
}

function clampedUniform(count, degree, lower, upper) {
  const knots = [];
  const spans = count - degree;
  for (let i = 0; i <= degree; i++) knots.push(lower);
  for (let i = 1; i < spans; i++) knots.push(lower + ((upper - lower) * i) / spans);
  for (let i = 0; i <= degree; i++) knots.push(upper);
  return knots;
}

function pairs(value) {
  // Curve and comb points arrive as one binary buffer of little-endian float64 (x, y) pairs.
  if (Array.isArray(value)) return value;
  const view = value instanceof DataView ? value : new DataView(value.buffer ?? value);
  const out = new Array(view.byteLength / 16);
  for (let i = 0; i < out.length; i++) {
    out[i] = [view.getFloat64(16 * i, true), view.getFloat64(16 * i + 8, true)];
  }
  return out;
}

function pathOf(points, map) {
  return points.map((p) => map(p).join(",")).join(" ");
}

function render({ model, el }) {
  const root = document.createElement("div");
  root.className = "dn-editor";
  el.appendChild(root);

  // --- toolbar -------------------------------------------------------------------------
  const bar = document.createElement("div");
  bar.className = "dn-bar";
  root.appendChild(bar);
  const toggles = {};
  for (const [key, label] of [["polygon", "control polygon"], ["construction", "construction"],
    ["comb", "curvature comb"], ["basis", "basis functions"]]) {
    const box = document.createElement("label");
    const input = document.createElement("input");
    input.type = "checkbox";
    input.dataset.toggle = key;
    input.addEventListener("change", () => {
      model.set("show", { ...model.get("show"), [key]: input.checked });
      model.save_changes();
    });
    box.append(input, " " + label);
    bar.appendChild(box);
    toggles[key] = input;
  }
  const degreeBox = document.createElement("label");
  const degreeInput = document.createElement("select");
  degreeInput.className = "dn-degree";
  degreeBox.append("degree ", degreeInput);
  bar.appendChild(degreeBox);
  const weightBox = document.createElement("label");
  const weightInput = document.createElement("input");
  weightInput.type = "number";
  weightInput.step = "0.1";
  weightInput.min = "0.01";
  weightInput.className = "dn-weight";
  weightBox.append("weight of P", document.createElement("span"), " ", weightInput);
  bar.appendChild(weightBox);
  // "points": a PointsEditor, which drags points and draws the kernel's labelled lines.
  const pointsMode = model.get("mode") === "points";
  const WIDTH = model.get("width");
  const HEIGHT = model.get("height");
  // A points editor shows only the weight box, and only when its points have weights.
  if (pointsMode) {
    for (const box of bar.children) if (box !== weightBox) box.style.display = "none";
    if (!model.get("state").weights) bar.style.display = "none";
  }
  // At least this many points stay when a point is deleted; 0: a points editor keeps its count.
  const minPoints = model.get("min_points");
  const legend = document.createElement("div");
  legend.className = "dn-legend";
  const message = document.createElement("div");
  message.className = "dn-message";
  root.appendChild(message);

  // --- drawing surface -------------------------------------------------------------------
  const svg = node("svg", { width: WIDTH, height: pointsMode ? HEIGHT : HEIGHT + STRIP + PANEL,
    class: "dn-svg" });
  root.appendChild(svg);
  root.appendChild(legend);
  node("rect", { x: 0, y: 0, width: WIDTH, height: HEIGHT, class: "dn-plot" }, svg);
  const combTeeth = node("path", { class: "dn-comb-teeth" }, svg);
  const combLine = node("polyline", { class: "dn-comb" }, svg);
  const polygon = node("polyline", { class: "dn-polygon" }, svg);
  const curveLine = node("polyline", { class: "dn-curve" }, svg);
  const supportLine = node("polyline", { class: "dn-support" }, svg);
  const levelGroup = node("g", { class: "dn-levels" }, svg);
  const lineGroup = node("g", { class: "dn-lines" }, svg);
  const pointGroup = node("g", { class: "dn-points" }, svg);
  const strip = node("g", { transform: `translate(0, ${HEIGHT})`, class: "dn-strip" }, svg);
  node("line", { x1: PAD, x2: WIDTH - PAD, y1: 22, y2: 22, class: "dn-axis" }, strip);
  const knotGroup = node("g", {}, strip);
  const marker = node("path", { d: "M0,24 l-7,12 l14,0 z", class: "dn-marker" }, strip);
  const panel = node("g", { transform: `translate(0, ${HEIGHT + STRIP})`, class: "dn-panel" }, svg);

  // --- view: fitted to a curve from Python, fixed while editing (a dragged point stays in it)
  let box = null;
  function fit(points) {
    const xs = points.map((p) => p[0]);
    const ys = points.map((p) => p[1]);
    let [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
    const size = Math.max(x1 - x0, y1 - y0, 1e-9);
    const margin = 0.12 * size;
    [x0, x1, y0, y1] = [x0 - margin, x1 + margin, y0 - margin, y1 + margin];
    // Equal aspect: the same scale on both axes, centred.
    const scale = Math.min((WIDTH - 2 * PAD) / (x1 - x0), (HEIGHT - 2 * PAD) / (y1 - y0));
    const cx = (x0 + x1) / 2;
    const cy = (y0 + y1) / 2;
    box = { scale, cx, cy };
  }
  const toScreen = (p) => [WIDTH / 2 + (p[0] - box.cx) * box.scale,
    HEIGHT / 2 - (p[1] - box.cy) * box.scale];
  const toWorld = (x, y) => [box.cx + (x - WIDTH / 2) / box.scale,
    box.cy - (y - HEIGHT / 2) / box.scale];
  const round = (x) => Math.round(x * 1e7) / 1e7;

  // --- local state, sent to the kernel one edit at a time --------------------------------
  let state = structuredClone(model.get("state"));
  let uValue = model.get("u");
  let selected = 0;
  let lastId = model.get("request");
  let inflight = 0; // requests sent and not yet drawn
  let dirty = false; // edits made while MAX_INFLIGHT requests were out
  let waiting = []; // pointer-event times of the edits the next drawing will show
  const sentWith = new Map(); // request id -> event times it carries
  const sentAt = new Map(); // request id -> when it was sent
  // Timings in ms, the last MEASURED of each: pointer event -> redrawn (latencies), sent ->
  // drawn (roundTrips, kernel and transport), the kernel's work (kernelTimes) and the
  // browser's redraw (drawTimes). Readable as data-* attributes once no edit is pending.
  const measured = { latencies: [], roundTrips: [], drawTimes: [], kernelTimes: [] };
  function measure(name, value) {
    const values = measured[name];
    values.push(Math.round(value * 10) / 10);
    if (values.length > MEASURED) values.shift();
  }
  function publishMeasures() {
    for (const [name, values] of Object.entries(measured)) root.dataset[name] = JSON.stringify(values);
  }
  publishMeasures();
  root.dataset.redraws = "0";
  root.dataset.pending = "0";

  function send() {
    // A counter of our own: the model's `request` may be an echo of an older one.
    lastId = Math.max(lastId, model.get("request")) + 1;
    const id = lastId;
    inflight += 1;
    dirty = false;
    sentWith.set(id, waiting);
    sentAt.set(id, performance.now());
    waiting = [];
    root.dataset.pending = "1";
    model.set("state", structuredClone(state));
    model.set("u", uValue);
    model.set("request", id);
    model.save_changes();
  }
  function edited(time) {
    waiting.push(time);
    drawPoints();
    if (inflight < MAX_INFLIGHT) send();
    else dirty = true;
  }

  function domain() {
    const k = state.knots;
    return [k[state.degree], k[k.length - state.degree - 1]];
  }
  const stripX = (u) => {
    const [a, b] = domain();
    return PAD + ((u - a) / (b - a)) * (WIDTH - 2 * PAD);
  };
  const stripU = (x) => {
    const [a, b] = domain();
    return a + ((x - PAD) / (WIDTH - 2 * PAD)) * (b - a);
  };

  // --- drawing ---------------------------------------------------------------------------
  function drawSelection() {
    // The part of the curve and the basis function of the selected control point.
    const drawing = model.get("drawing");
    if (drawing.curve) {
      const curve = pairs(drawing.curve);
      supportLine.setAttribute("points", pathOf(supported(curve, drawing.per_span), toScreen));
    }
    panel.childNodes.forEach((line, i) => line.classList.toggle("dn-basis-selected", i === selected));
  }
  function supported(curve, perSpan) {
    // The samples on [U[k], U[k + p + 1]], where the selected point P_k acts: the kernel
    // samples each non-empty span at `perSpan` even steps, then the end of the domain.
    const { knots, degree } = state;
    const inner = knots.slice(degree, knots.length - degree);
    const breaks = inner.filter((u, i) => i === 0 || u > inner[i - 1]);
    const [lower, upper] = [knots[selected], knots[selected + degree + 1]];
    return curve.filter((_, j) => {
      const span = Math.min(Math.floor(j / perSpan), breaks.length - 1);
      const u = span === breaks.length - 1 ? breaks[span]
        : breaks[span] + ((j % perSpan) / perSpan) * (breaks[span + 1] - breaks[span]);
      return u >= lower && u <= upper;
    });
  }

  function drawPoints() {
    const points = state.control_points;
    polygon.setAttribute("points", pathOf(points, toScreen));
    while (pointGroup.childNodes.length > points.length) pointGroup.lastChild.remove();
    while (pointGroup.childNodes.length < points.length) {
      const index = pointGroup.childNodes.length;
      const circle = node("circle", { r: 6, class: "dn-point" }, pointGroup);
      circle.dataset.index = index;
      startDrag(circle, (event, first) => movePoint(Number(circle.dataset.index), event, first));
    }
    points.forEach((p, i) => {
      const [x, y] = toScreen(p);
      const circle = pointGroup.childNodes[i];
      circle.dataset.index = i;
      circle.setAttribute("cx", x);
      circle.setAttribute("cy", y);
      const w = state.weights ? state.weights[i] : 1;
      circle.setAttribute("r", 4 + 3 * Math.min(Math.sqrt(w), 3));
      circle.classList.toggle("dn-selected", i === selected);
    });
    drawKnots();
    const w = state.weights ? state.weights[selected] : 1;
    weightBox.querySelector("span").textContent = String(selected);
    if (document.activeElement !== weightInput) weightInput.value = w;
    if (pointsMode) {
      polygon.style.display = "none";
      return;
    }
    const options = [];
    for (let p = 1; p < Math.min(points.length, 8); p++) options.push(p);
    if (degreeInput.options.length !== options.length) {
      degreeInput.replaceChildren(...options.map((p) => new Option(String(p), String(p))));
    }
    degreeInput.value = String(state.degree);
  }

  function drawKnots() {
    if (pointsMode) return;
    const knots = state.knots;
    while (knotGroup.childNodes.length > knots.length) knotGroup.lastChild.remove();
    while (knotGroup.childNodes.length < knots.length) {
      const tick = node("rect", { width: 6, height: 14, class: "dn-knot" }, knotGroup);
      startDrag(tick, (event, first) => moveKnot(Number(tick.dataset.index), event, first));
    }
    const seen = new Map();
    knots.forEach((u, i) => {
      const key = u.toFixed(9);
      const stack = seen.get(key) || 0;
      seen.set(key, stack + 1);
      const tick = knotGroup.childNodes[i];
      tick.dataset.index = i;
      tick.setAttribute("x", stripX(u) - 3);
      tick.setAttribute("y", 15 - 7 * stack);
      const inner = i > state.degree && i < knots.length - state.degree - 1;
      tick.classList.toggle("dn-inner", inner);
    });
    marker.setAttribute("transform", `translate(${stripX(uValue)}, 0)`);
  }

  // A raster under the lines (PointsEditor with a `Raster`): PNG bytes shown through a blob
  // URL, the previous URL released when the next one replaces it.
  let raster = null;
  let rasterUrl = null;
  function drawRaster(image) {
    if (!image) {
      if (raster) raster.remove();
      raster = null;
      return;
    }
    if (!raster) {
      raster = node("image", { preserveAspectRatio: "none", class: "dn-raster" });
      svg.insertBefore(raster, svg.childNodes[1]); // above the plot's background only
    }
    const [x0, x1, y0, y1] = image.extent;
    const [left, top] = toScreen([x0, y1]);
    const [right, bottom] = toScreen([x1, y0]);
    const url = URL.createObjectURL(new Blob([image.png], { type: "image/png" }));
    Object.entries({ x: left, y: top, width: right - left, height: bottom - top, href: url })
      .forEach(([key, value]) => raster.setAttribute(key, value));
    if (rasterUrl) URL.revokeObjectURL(rasterUrl);
    rasterUrl = url;
  }

  function drawLines(drawing) {
    if (!drawing.lines) return;
    drawRaster(drawing.image);
    lineGroup.replaceChildren();
    legend.replaceChildren();
    drawing.lines.forEach(({ label, data }, i) => {
      const color = COLORS[i % COLORS.length];
      node("polyline", { points: pathOf(pairs(data), toScreen), class: "dn-line", stroke: color },
        lineGroup);
      const entry = document.createElement("span");
      entry.className = "dn-legend-entry";
      entry.style.borderColor = color;
      entry.textContent = label;
      legend.appendChild(entry);
    });
  }

  function drawCurve() {
    const drawing = model.get("drawing");
    message.textContent = drawing.error || "";
    if (pointsMode) return drawLines(drawing);
    if (!drawing.curve) return;
    const curve = pairs(drawing.curve);
    curveLine.setAttribute("points", pathOf(curve, toScreen));
    const show = model.get("show");
    polygon.style.display = show.polygon ? "" : "none";
    levelGroup.replaceChildren();
    if (show.construction && drawing.levels) {
      drawing.levels.slice(1).forEach((level, r) => {
        node("polyline", { points: pathOf(level, toScreen), class: `dn-level dn-level-${r}` },
          levelGroup);
        for (const p of level) {
          const [x, y] = toScreen(p);
          node("circle", { cx: x, cy: y, r: 3, class: "dn-level-point" }, levelGroup);
        }
      });
      const [x, y] = toScreen(drawing.point);
      node("circle", { cx: x, cy: y, r: 5, class: "dn-on-curve" }, levelGroup);
    }
    if (show.comb && drawing.comb) {
      const comb = pairs(drawing.comb);
      combLine.setAttribute("points", pathOf(comb, toScreen));
      combTeeth.setAttribute("d", curve.map((p, i) => {
        const [a, b] = [toScreen(p), toScreen(comb[i])];
        return `M${a[0]},${a[1]}L${b[0]},${b[1]}`;
      }).join(""));
    } else {
      combLine.setAttribute("points", "");
      combTeeth.setAttribute("d", "");
    }
    // The basis functions change with the knots, the degree and the weights only.
    const revision = show.basis && drawing.basis ? drawing.basis.revision : null;
    if (revision !== panel.revision) {
      panel.revision = revision;
      panel.replaceChildren();
    }
    if (show.basis && drawing.basis && !panel.hasChildNodes()) {
      const { u, rows } = drawing.basis;
      const [a, b] = [u[0], u[u.length - 1]];
      const x = (t) => PAD + ((t - a) / (b - a)) * (WIDTH - 2 * PAD);
      const y = (value) => PANEL - 8 - value * (PANEL - 20);
      rows.forEach(([first, values], i) => {
        const points = values.map((value, k) => `${x(u[first + k])},${y(value)}`).join(" ");
        node("polyline", { points, class: "dn-basis", stroke: COLORS[i % COLORS.length] }, panel);
      });
    }
    drawSelection();
    for (const key of Object.keys(toggles)) toggles[key].checked = Boolean(show[key]);
  }

  // --- interaction -----------------------------------------------------------------------
  function startDrag(element, onMove) {
    element.addEventListener("pointerdown", (event) => {
      if (event.button !== 0) return;
      event.preventDefault();
      event.stopPropagation();
      element.setPointerCapture(event.pointerId);
      onMove(event, true);
      const move = (e) => onMove(e, false);
      const stop = () => {
        element.removeEventListener("pointermove", move);
        element.removeEventListener("pointerup", stop);
        element.removeEventListener("pointercancel", stop);
      };
      element.addEventListener("pointermove", move);
      element.addEventListener("pointerup", stop);
      element.addEventListener("pointercancel", stop);
    });
  }
  function local(event) {
    const rect = svg.getBoundingClientRect();
    return [event.clientX - rect.left, event.clientY - rect.top];
  }
  function movePoint(index, event, first) {
    selected = index;
    if (first) {
      drawPoints();
      return drawSelection();
    }
    const [x, y] = local(event);
    const [wx, wy] = toWorld(Math.min(Math.max(x, 0), WIDTH), Math.min(Math.max(y, 0), HEIGHT));
    state.control_points[index] = [round(wx), round(wy)];
    edited(event.timeStamp);
  }
  function moveKnot(index, event, first) {
    const p = state.degree;
    const knots = state.knots;
    if (first || index <= p || index >= knots.length - p - 1) return;
    const [x] = local(event);
    // An interior knot stays between its neighbours.
    const u = Math.min(Math.max(stripU(x), knots[index - 1]), knots[index + 1]);
    knots[index] = round(u);
    edited(event.timeStamp);
  }
  startDrag(marker, (event, first) => {
    if (first) return;
    const [a, b] = domain();
    uValue = round(Math.min(Math.max(stripU(local(event)[0]), a), b));
    edited(event.timeStamp);
  });

  function restructure(points, weights, degree) {
    if (pointsMode) {
      state = { ...state, control_points: points, weights };
      selected = Math.min(selected, points.length - 1);
      return edited(performance.now());
    }
    const [a, b] = domain();
    state = { control_points: points, weights, degree,
      knots: clampedUniform(points.length, degree, a, b) };
    selected = Math.min(selected, points.length - 1);
    edited(performance.now());
  }
  svg.addEventListener("dblclick", (event) => {
    if (pointsMode && !minPoints) return;
    const [x, y] = local(event);
    if (y > HEIGHT) return;
    const q = toWorld(x, y);
    const points = state.control_points;
    // The new point goes into the leg of the polygon nearest to the click.
    let best = 0;
    let bestDistance = Infinity;
    for (let i = 0; i + 1 < points.length; i++) {
      const [a, b] = [points[i], points[i + 1]];
      const d = [b[0] - a[0], b[1] - a[1]];
      const t = Math.min(Math.max(((q[0] - a[0]) * d[0] + (q[1] - a[1]) * d[1]) /
        (d[0] * d[0] + d[1] * d[1] || 1), 0), 1);
      const distance = Math.hypot(a[0] + t * d[0] - q[0], a[1] + t * d[1] - q[1]);
      if (distance < bestDistance) [best, bestDistance] = [i, distance];
    }
    const newPoints = [...points.slice(0, best + 1), [round(q[0]), round(q[1])],
      ...points.slice(best + 1)];
    const weights = state.weights && [...state.weights.slice(0, best + 1), 1,
      ...state.weights.slice(best + 1)];
    selected = best + 1;
    restructure(newPoints, weights, state.degree);
  });
  pointGroup.addEventListener("contextmenu", (event) => {
    event.preventDefault();
    if (pointsMode && !minPoints) return;
    const index = Number(event.target.dataset.index);
    const points = state.control_points;
    const fewest = pointsMode ? minPoints : state.degree + 1;
    if (Number.isNaN(index) || points.length <= fewest) {
      message.textContent = pointsMode ? `at least ${fewest} points stay`
        : `a curve of degree ${state.degree} needs at least ${fewest} points`;
      return;
    }
    const weights = state.weights && state.weights.filter((_, i) => i !== index);
    restructure(points.filter((_, i) => i !== index), weights, state.degree);
  });
  function setWeight(index, value, time) {
    if (!(value > 0) || !Number.isFinite(value)) {
      message.textContent = "a weight must be a positive number";
      return;
    }
    state.weights = state.weights || state.control_points.map(() => 1);
    state.weights[index] = round(value);
    edited(time);
  }
  pointGroup.addEventListener("wheel", (event) => {
    const index = Number(event.target.dataset.index);
    if ((pointsMode && !state.weights) || Number.isNaN(index)) return;
    event.preventDefault();
    selected = index;
    const w = state.weights ? state.weights[index] : 1;
    setWeight(index, w * Math.pow(1.1, -Math.sign(event.deltaY)), event.timeStamp);
  }, { passive: false });
  weightInput.addEventListener("change", () => setWeight(selected, Number(weightInput.value),
    performance.now()));
  degreeInput.addEventListener("change", () => {
    restructure(state.control_points, state.weights, Number(degreeInput.value));
  });

  // --- from the kernel -------------------------------------------------------------------
  function onDrawing() {
    const drawing = model.get("drawing");
    const start = performance.now();
    drawCurve();
    const done = performance.now();
    measure("drawTimes", done - start);
    measure("kernelTimes", drawing.kernel_ms);
    if (sentAt.has(drawing.request)) {
      measure("roundTrips", done - sentAt.get(drawing.request));
      sentAt.delete(drawing.request);
    }
    root.dataset.redraws = String(Number(root.dataset.redraws) + 1);
    // ipywidgets merges edits queued behind a busy kernel into one message: a drawing
    // answers its own request and every earlier one.
    const answered = [...sentWith.keys()].filter((id) => id <= drawing.request);
    if (answered.length) {
      for (const id of answered) {
        for (const t of sentWith.get(id)) measure("latencies", done - t);
        sentWith.delete(id);
        sentAt.delete(id);
      }
      inflight -= answered.length;
      if (drawing.error && inflight === 0) {
        // The kernel refused the edit: go back to the last curve it accepted.
        state = structuredClone(model.get("state"));
        drawPoints();
      }
      if (dirty) send();
      else if (inflight === 0) {
        publishMeasures();
        root.dataset.pending = "0";
      }
    }
  }
  function onU() {
    // A parameter set from Python.
    if (inflight > 0 || dirty) return;
    uValue = model.get("u");
    drawKnots();
  }
  function onState() {
    // A curve assigned from Python (not an echo of our own edit while one is in flight).
    if (inflight > 0 || dirty) return;
    state = structuredClone(model.get("state"));
    fit(state.control_points);
    drawPoints();
  }
  model.on("change:drawing", onDrawing);
  model.on("change:state", onState);
  model.on("change:u", onU);

  // A points editor frames its lines too: what the kernel draws may reach beyond the points.
  const first = model.get("drawing");
  const lines = pointsMode ? (first.lines || []).flatMap(({ data }) => pairs(data)) : [];
  if (pointsMode && first.image) {
    const [x0, x1, y0, y1] = first.image.extent;
    lines.push([x0, y0], [x1, y1]);
  }
  fit([...state.control_points, ...lines]);
  drawPoints();
  drawCurve();
  return () => {
    model.off("change:drawing", onDrawing);
    model.off("change:state", onState);
    model.off("change:u", onU);
    if (rasterUrl) URL.revokeObjectURL(rasterUrl);
  };
}

export default { render };
