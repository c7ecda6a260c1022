// magcal live: polls /status.json and shows what to turn to next (the guidance), the coverage of
// the field directions (a sphere to turn and MotionCal's flat map of regions), the attitudes
// flown against the box, and the fit. Plain canvas 2D: the page's Content-Security-Policy allows
// scripts and styles from its own server only.
"use strict";

const $ = (id) => document.getElementById(id);
const DEG = Math.PI / 180;
// A number to d decimals; a negative number that rounds to zero is shown without its sign.
const fmt = (v, d) => {
  if (v === null || v === undefined) return "-";
  const t = Number(v).toFixed(d);
  return /^-0(\.0*)?$/.test(t) ? t.slice(1) : t;
};
const known = (v) => v !== null && v !== undefined;

// Sets the text of `id`, only when it changed: a live region announces every change, and the
// page is redrawn twice a second.
function text(id, s) {
  const e = $(id);
  if (e.textContent !== s) e.textContent = s;
}

// Colours shared by the figures and the legend (live.css).
const COLOUR = {
  full: [159, 214, 159], // a region holding 3 readings or more
  some: [214, 236, 214], // 1 or 2
  none: [255, 255, 255],
  dot: "#1f4e9c",
  now: "#d62728",
  later: "#e07b00",
  axis: "#333",
  flown: "#2ca02c",
};

/* ---------- Directions and rotations (sensor frame: x, y, z) ---------- */

// The unit vector at longitude `lon` (from x towards y) and latitude `lat` (towards z), degrees.
function unitOf(lon, lat) {
  const c = Math.cos(lat * DEG);
  return [c * Math.cos(lon * DEG), c * Math.sin(lon * DEG), Math.sin(lat * DEG)];
}

// The longitude in [0, 360) and the latitude of a vector, degrees.
function lonLatOf(v) {
  const n = Math.hypot(v[0], v[1], v[2]) || 1;
  const lon = (Math.atan2(v[1], v[0]) / DEG + 360) % 360;
  return [lon, Math.asin(Math.max(-1, Math.min(1, v[2] / n))) / DEG];
}

// The product of two 3x3 matrices (arrays of rows).
function times(A, B) {
  return A.map((row) => [0, 1, 2].map((j) => row[0] * B[0][j] + row[1] * B[1][j] + row[2] * B[2][j]));
}

// The matrix R applied to the vector v.
function apply(R, v) {
  return R.map((row) => row[0] * v[0] + row[1] * v[1] + row[2] * v[2]);
}

// Rotations by `a` radians about the screen's horizontal (x) and vertical (y) axes.
function aboutX(a) {
  const c = Math.cos(a), s = Math.sin(a);
  return [[1, 0, 0], [0, c, -s], [0, s, c]];
}
function aboutY(a) {
  const c = Math.cos(a), s = Math.sin(a);
  return [[c, 0, s], [0, 1, 0], [-s, 0, c]];
}

/* ---------- The plan: what to turn to ---------- */

// An attitude in the pilot's words, for a status from before plans carried their own words.
function attitudeWords(a) {
  if (!known(a.roll_deg)) return "";
  const m = a.magnetic_heading_deg;
  const heading = known(m)
    ? `magnetic heading ${fmt(m, 0)} (true ${fmt(a.true_heading_deg, 0)})`
    : `true heading ${fmt(a.true_heading_deg, 0)}`;
  return `roll ${fmt(a.roll_deg, 0)}, pitch ${fmt(a.pitch_deg, 0)}, ${heading} deg`;
}

// The targets to turn to, the first the one for now: the status's plan, or, from a status
// without one, its next attitude. Each has `field_direction` where the status gives it.
function targetsOf(s) {
  if (Array.isArray(s.plan) && s.plan.length > 0) return s.plan;
  if (s.next) return [{ ...s.next, words: attitudeWords(s.next), flown: null }];
  return [];
}

// What a target asks for, in words.
function wordsOf(t) {
  if (t.words) return t.words;
  const w = attitudeWords(t);
  if (w) return w;
  if (!t.field_direction) return "-";
  const [lon, lat] = lonLatOf(t.field_direction);
  return `field towards longitude ${fmt(lon, 0)}, latitude ${fmt(lat, 0)} deg`;
}

// How much of a target is flown: "(3/10 readings)", or the readings wanted alone.
function countOf(t) {
  if (!known(t.readings)) return "";
  return known(t.flown) ? `(${t.flown}/${t.readings} readings)` : `(${t.readings} readings)`;
}

/* ---------- The guidance panel ---------- */

// Now, then, and the banners of a calibration done or a stream stopped.
function showGuidance(s, targets) {
  if (targets.length > 0) {
    text("next", wordsOf(targets[0]));
    text("flown", countOf(targets[0]));
  } else if (s.next_error) {
    text("next", s.next_error);
    text("flown", "");
  }
  const later = targets.slice(1, 3).map(wordsOf);
  $("then-line").hidden = later.length === 0;
  text("then", later.join("; "));
  const done = s.done === true;
  const stopped = known(s.stream_end) || s.ended === true;
  $("steps").hidden = done;
  $("guide").classList.toggle("finished", done || stopped);
  showDone(s, done);
  showStopped(s, stopped);
  showProgress(s);
}

// What the set in `out` holds, in words.
function writtenWords(s) {
  if (!known(s.written_fit)) return `nothing written to ${s.out} yet`;
  return `${s.out} holds fit ${s.written_fit} (${s.written_usable ? "usable" : "not usable"})`;
}

// The DONE banner: the heading budget met, and at which fit.
function showDone(s, done) {
  $("done").hidden = !done;
  if (!done) return;
  const at = known(s.done_fit) ? ` at fit ${s.done_fit}` : "";
  text("done-title", `DONE: heading budget met${at}`);
  text(
    "done-detail",
    `heading error ${fmt(s.heading_predicted_deg, 2)} deg predicted against a budget of ${fmt(s.heading_budget_deg, 1)} deg; ${writtenWords(s)}.${s.ended === true || known(s.stream_end) ? "" : " You can stop turning."}`,
  );
}

// The banner of a stream that stopped: why, and what the calibration set holds.
function showStopped(s, stopped) {
  $("stopped").hidden = !stopped;
  if (!stopped) return;
  text("stopped-title", `The stream stopped: ${s.stream_end || "the source ended"}.`);
  text("stopped-detail", `${writtenWords(s)}.`);
}

// How far the predicted heading error has come towards the budget: 0 at ten times the budget or
// more, 1 at the budget or less, on a log scale (each halving of the error counts the same).
function budgetFraction(predicted, budget) {
  if (!known(predicted) || !known(budget) || budget <= 0) return null;
  const f = Math.log10((10 * budget) / predicted);
  return Math.max(0, Math.min(1, f));
}

// The progress sentence and the bar of the predicted heading error against the budget.
function showProgress(s) {
  const budget = s.heading_budget_deg, predicted = s.heading_predicted_deg;
  const sentence = s.progress
    || (known(predicted) ? `predicted heading error ${fmt(predicted, 2)} deg -> budget ${fmt(budget, 1)} deg` : "no heading error predicted yet");
  text("progress", sentence);
  const f = budgetFraction(predicted, budget);
  const bar = $("bar"), fill = $("bar-fill");
  // A CSSOM width: the policy refuses style attributes, not styles set from its own script.
  fill.style.width = `${Math.round(100 * (f ?? 0))}%`;
  fill.classList.toggle("met", f === 1);
  bar.setAttribute("aria-valuenow", String(Math.round(100 * (f ?? 0))));
  bar.setAttribute("aria-valuetext", known(predicted) ? `${fmt(predicted, 2)} deg predicted, budget ${fmt(budget, 1)} deg` : "no prediction yet");
  if (known(budget)) {
    // Two significant digits: a budget of 0.2 deg reads 2, 0.63 and 0.2.
    const sig = (v) => String(Number(v.toPrecision(2)));
    text("bar-from", `${sig(10 * budget)} deg`);
    text("bar-mid", `${sig(Math.sqrt(10) * budget)} deg`);
    text("bar-to", `${sig(budget)} deg (budget)`);
  }
  const counts = known(s.targets_flown) ? ` Targets flown ${s.targets_flown}, plans superseded ${s.plans_superseded ?? 0}.` : "";
  const now = f === null ? "" : ` Now ${Math.round(100 * f)} % of the way.`;
  text("bar-says", `The bar: the predicted heading error (95th percentile) on a log scale, empty at ten times the budget, full at the budget.${now}${counts}`);
}

/* ---------- The sphere to turn ---------- */

// The view of the sphere, kept across statuses: R turns the sensor frame into the screen's
// (x right, y up, z towards the viewer).
const globe = {
  R: frontView(),
  spinning: !window.matchMedia("(prefers-reduced-motion: reduce)").matches,
  drag: null, // the pointer's last position while dragging
  dirty: true, // to be drawn at the next frame
  last: 0, // the time of the last turn step, ms
  status: null,
  targets: [],
  bands: [],
};
const SPIN_DEG_PER_S = 8;

// The view the page opens with: z up, x to the front left, y to the front right, seen from 20
// degrees above the xy plane.
function frontView() {
  const sensorToScreen = [[0, 1, 0], [0, 0, 1], [1, 0, 0]];
  return times(aboutX(20 * DEG), times(aboutY(-35 * DEG), sensorToScreen));
}

// MotionCal's regions as bands of latitude, each cut into cells of longitude, to find the
// region of a direction without a search through all 100.
function bandsOf(bounds) {
  const bands = new Map();
  bounds.forEach((b, k) => {
    const key = b.sin_latitude.join();
    if (!bands.has(key)) bands.set(key, { lo: b.sin_latitude[0], hi: b.sin_latitude[1], cells: [] });
    bands.get(key).cells.push({ t0: b.turn[0], t1: b.turn[1], k });
  });
  for (const band of bands.values()) band.cells.sort((a, b) => a.t0 - b.t0);
  return [...bands.values()].sort((a, b) => a.lo - b.lo);
}

// The number of the region holding the direction at `turn` of longitude (0 to 1) and sine of
// latitude `z`, or -1.
function regionAt(bands, turn, z) {
  for (const band of bands) {
    if (z > band.hi) continue;
    for (const c of band.cells) if (turn < c.t1) return c.k;
    return band.cells[band.cells.length - 1].k;
  }
  return -1;
}

// The colour of a region by the readings it holds, as on the flat map.
function regionColour(n) {
  return n >= 3 ? COLOUR.full : n > 0 ? COLOUR.some : COLOUR.none;
}

// The near side of the sphere pixel by pixel: each pixel's direction in the sensor frame, the
// colour of the region it falls in, lit from the upper left so that the ball looks round, and
// darker where the region changes (the regions' edges).
function shadeSphere(g, geo, R, s, bands) {
  const { w, h, cx, cy, r } = geo;
  const img = g.createImageData(w, h), d = img.data;
  const L = [-0.45, 0.55, 0.7]; // the light, towards the viewer's upper left
  const above = new Int16Array(w).fill(-2); // the regions of the row above
  for (let py = 0; py < h; py++) {
    let left = -2;
    for (let px = 0; px < w; px++) {
      const X = (px + 0.5 - cx) / r, Y = (cy - py - 0.5) / r, q = X * X + Y * Y;
      if (q > 1) {
        above[px] = left = -2;
        continue;
      }
      const Z = Math.sqrt(1 - q);
      // The screen's direction back in the sensor frame: R's transpose.
      const vx = R[0][0] * X + R[1][0] * Y + R[2][0] * Z;
      const vy = R[0][1] * X + R[1][1] * Y + R[2][1] * Z;
      const vz = R[0][2] * X + R[1][2] * Y + R[2][2] * Z;
      const turn = ((Math.atan2(vy, vx) / (2 * Math.PI)) + 1) % 1;
      const k = bands.length ? regionAt(bands, turn, vz) : -1;
      const edge = (left !== -2 && left !== k) || (above[px] !== -2 && above[px] !== k);
      const light = (0.72 + 0.28 * Math.max(0, X * L[0] + Y * L[1] + Z * L[2])) * (edge ? 0.78 : 1);
      const c = regionColour(k >= 0 ? s.regions[k] || 0 : 0);
      const i = 4 * (py * w + px);
      d[i] = c[0] * light; d[i + 1] = c[1] * light; d[i + 2] = c[2] * light; d[i + 3] = 255;
      above[px] = left = k;
    }
  }
  g.putImageData(img, 0, 0);
}

// Where a sensor-frame vector falls on the canvas, and whether it is on the near side.
function projector(geo, R) {
  return (v) => {
    const p = apply(R, v);
    return { x: geo.cx + geo.r * p[0], y: geo.cy - geo.r * p[1], near: p[2] >= 0 };
  };
}

// The calibrated directions on one side of the sphere: near ones solid, far ones faint (seen
// through the ball), the newest reading ringed.
function drawDirections(g, s, project, near) {
  g.fillStyle = COLOUR.dot;
  g.globalAlpha = near ? 1 : 0.22;
  for (const [lon, lat] of s.directions) {
    const p = project(unitOf(lon, lat));
    if (p.near !== near) continue;
    g.beginPath(); g.arc(p.x, p.y, near ? 2 : 1.5, 0, 2 * Math.PI); g.fill();
  }
  g.globalAlpha = 1;
  const newest = s.directions[s.directions.length - 1];
  if (near && newest) {
    const p = project(unitOf(newest[0], newest[1]));
    g.globalAlpha = p.near ? 1 : 0.4;
    ring(g, p.x, p.y, 4.5, "#111", 2.5);
    g.globalAlpha = 1;
  }
}

// A ring of radius r, dashed when `dashed`.
function ring(g, x, y, r, colour, width, dashed = false) {
  g.strokeStyle = colour; g.lineWidth = width;
  g.setLineDash(dashed ? [4, 3] : []);
  g.beginPath(); g.arc(x, y, r, 0, 2 * Math.PI); g.stroke();
  g.setLineDash([]); g.lineWidth = 1;
}

// The targets of the plan: the one for now a big red ring with a cross, the later ones small
// orange rings numbered; a target on the far side is dashed and faint.
function drawTargets(g, targets, project) {
  const at = targets.map((t) => (t.field_direction ? project(t.field_direction) : null));
  for (let k = at.length - 1; k >= 0; k--) {
    const p = at[k];
    if (!p) continue;
    const now = k === 0;
    g.globalAlpha = p.near ? 1 : 0.55;
    ring(g, p.x, p.y, now ? 11 : 6, now ? COLOUR.now : COLOUR.later, now ? 3.5 : 2.5, !p.near);
    g.fillStyle = now ? COLOUR.now : COLOUR.later;
    g.font = now ? "bold 13px system-ui, sans-serif" : "12px system-ui, sans-serif";
    // The label on the side of the sphere's centre, so that it stays on the canvas.
    const label = now ? (p.near ? "now" : "now (far side)") : String(k + 1);
    const inward = p.x > g.canvas.width / 2 ? -1 : 1;
    g.textAlign = inward < 0 ? "right" : "left";
    g.fillText(label, p.x + inward * (now ? 14 : 8), p.y - (now ? 10 : 6));
    g.textAlign = "start";
    if (now) {
      g.strokeStyle = COLOUR.now; g.lineWidth = 2;
      g.beginPath(); g.moveTo(p.x - 5, p.y); g.lineTo(p.x + 5, p.y); g.moveTo(p.x, p.y - 5); g.lineTo(p.x, p.y + 5); g.stroke();
      g.lineWidth = 1;
    }
  }
  g.globalAlpha = 1;
}

// The sensor's axes x, y and z, from the surface outwards, labelled; those pointing away from the
// viewer dashed and faint.
function drawAxes(g, project) {
  g.font = "bold 14px system-ui, sans-serif";
  g.textAlign = "center"; g.textBaseline = "middle";
  [["x", [1, 0, 0]], ["y", [0, 1, 0]], ["z", [0, 0, 1]]].forEach(([name, a]) => {
    const from = project(a), to = project(a.map((c) => 1.32 * c)), label = project(a.map((c) => 1.44 * c));
    g.globalAlpha = from.near ? 1 : 0.45;
    g.strokeStyle = COLOUR.axis; g.lineWidth = 2;
    g.setLineDash(from.near ? [] : [5, 4]);
    g.beginPath(); g.moveTo(from.x, from.y); g.lineTo(to.x, to.y); g.stroke();
    g.setLineDash([]); g.lineWidth = 1;
    g.fillStyle = COLOUR.axis;
    g.fillText(name, label.x, label.y);
  });
  g.globalAlpha = 1;
  g.textAlign = "start"; g.textBaseline = "alphabetic";
}

// The whole sphere as the view stands: the shaded near side, the far side's dots through it,
// its outline, the near dots, the targets and the axes.
function drawGlobe() {
  const c = $("globe"), g = c.getContext("2d"), s = globe.status;
  const geo = { w: c.width, h: c.height, cx: c.width / 2, cy: c.height / 2, r: 0.34 * Math.min(c.width, c.height) };
  g.clearRect(0, 0, geo.w, geo.h);
  if (!s) return;
  const project = projector(geo, globe.R);
  shadeSphere(g, geo, globe.R, s, globe.bands);
  drawDirections(g, s, project, false);
  g.strokeStyle = "#777";
  g.beginPath(); g.arc(geo.cx, geo.cy, geo.r, 0, 2 * Math.PI); g.stroke();
  drawDirections(g, s, project, true);
  drawTargets(g, globe.targets, project);
  drawAxes(g, project);
}

// The sphere's text: where the next target and the newest reading are, for readers of the
// page who do not see the figure.
function describeGlobe(s, targets) {
  const t = targets[0];
  const target = t && t.field_direction
    ? (() => { const [lon, lat] = lonLatOf(t.field_direction); return `The next target: the field at longitude ${fmt(lon, 0)}, latitude ${fmt(lat, 0)} deg in the sensor frame. `; })()
    : s.done === true ? "The budget is met: no more targets. " : "No target yet. ";
  const newest = s.directions[s.directions.length - 1];
  const now = newest ? `The newest reading: longitude ${fmt(newest[0], 0)}, latitude ${fmt(newest[1], 0)} deg. ` : "";
  text("globe-says", `${target}${now}${s.directions.length} directions shown.`);
}

// A new status for the sphere: drawn at the next frame, in the view it had.
function updateGlobe(s, targets) {
  globe.status = s;
  globe.targets = targets;
  globe.bands = bandsOf(s.region_bounds || []);
  globe.dirty = true;
  describeGlobe(s, targets);
}

// Turns the view by a drag of (dx, dy) pixels: a drag to the right turns the near side right.
function turnView(dx, dy) {
  globe.R = times(aboutX(dy * 0.01), times(aboutY(dx * 0.01), globe.R));
  globe.dirty = true;
}

// Starts or stops the sphere turning by itself, and says so on its button.
function setSpinning(on) {
  globe.spinning = on;
  const b = $("spin");
  b.textContent = on ? "stop turning" : "turn by itself";
  b.setAttribute("aria-pressed", String(on));
}

// Each frame: the slow turn about the screen's vertical (at most 30 steps a second: the sphere is
// shaded pixel by pixel, and the page shares the machine with the fits), and a drawing when
// anything changed.
function frame(t) {
  const dt = Math.min(0.1, (t - (globe.last || t)) / 1000);
  if (globe.spinning && !globe.drag && globe.status && dt >= 1 / 30) {
    globe.R = times(aboutY(SPIN_DEG_PER_S * DEG * dt), globe.R);
    globe.dirty = true;
  }
  if (dt >= 1 / 30 || !globe.last) globe.last = t;
  if (globe.dirty) {
    globe.dirty = false;
    drawGlobe();
  }
  requestAnimationFrame(frame);
}

// Mouse, pen and touch drags (pointer events), the arrow keys, and the two buttons.
function listenToGlobe() {
  const c = $("globe");
  c.addEventListener("pointerdown", (e) => {
    globe.drag = { x: e.clientX, y: e.clientY };
    setSpinning(false);
    c.setPointerCapture(e.pointerId);
    e.preventDefault();
  });
  c.addEventListener("pointermove", (e) => {
    if (!globe.drag) return;
    turnView(e.clientX - globe.drag.x, e.clientY - globe.drag.y);
    globe.drag = { x: e.clientX, y: e.clientY };
  });
  const release = () => { globe.drag = null; };
  c.addEventListener("pointerup", release);
  c.addEventListener("pointercancel", release);
  c.addEventListener("keydown", (e) => {
    const step = { ArrowLeft: [-17, 0], ArrowRight: [17, 0], ArrowUp: [0, -17], ArrowDown: [0, 17] }[e.key];
    if (!step) return;
    setSpinning(false);
    turnView(step[0], step[1]);
    e.preventDefault();
  });
  $("spin").addEventListener("click", () => setSpinning(!globe.spinning));
  $("reset").addEventListener("click", () => { globe.R = frontView(); globe.dirty = true; });
  setSpinning(globe.spinning);
}

/* ---------- Axes of the flat figures ---------- */

// Ticks at 1, 2 or 5 times a power of ten, about n of them between lo and hi.
function ticks(lo, hi, n) {
  const raw = (hi - lo) / n, p = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((m) => m * p).find((s) => s >= raw);
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9; v += step) out.push(Math.round(v / step) * step);
  return out;
}

// A frame around the plot area, with a tick and its label at each (value, text) along the bottom
// (`xs`) and the left (`ys`), and the axes' titles.
function frameAxes(g, a, xs, ys, xTitle, yTitle) {
  g.strokeStyle = "#666"; g.fillStyle = "#333";
  g.strokeRect(a.x0, a.y0, a.x1 - a.x0, a.y1 - a.y0);
  g.font = "11px system-ui, sans-serif";
  g.textAlign = "center"; g.textBaseline = "top";
  for (const [x, label] of xs) {
    g.beginPath(); g.moveTo(x, a.y1); g.lineTo(x, a.y1 + 4); g.stroke();
    g.fillText(label, x, a.y1 + 6);
  }
  g.textAlign = "right"; g.textBaseline = "middle";
  for (const [y, label] of ys) {
    g.beginPath(); g.moveTo(a.x0 - 4, y); g.lineTo(a.x0, y); g.stroke();
    g.fillText(label, a.x0 - 6, y);
  }
  g.font = "12px system-ui, sans-serif";
  g.textAlign = "center"; g.textBaseline = "bottom";
  g.fillText(xTitle, (a.x0 + a.x1) / 2, a.y1 + 38);
  verticalText(g, yTitle, a.x0 - 34, (a.y0 + a.y1) / 2);
  g.textAlign = "start"; g.textBaseline = "alphabetic";
}

// Text turned to read upwards, centred at (x, y).
function verticalText(g, s, x, y) {
  g.save();
  g.translate(x, y); g.rotate(-Math.PI / 2);
  g.textAlign = "center"; g.textBaseline = "middle";
  g.fillText(s, 0, 0);
  g.restore();
}

/* ---------- The flat map of MotionCal's regions ---------- */

// Calibrated directions on MotionCal's 100 equal-area regions: longitude (0 to 360 degrees from
// the sensor's x axis towards its y axis) against the sine of the latitude (towards z), a
// projection in which every region is a rectangle of the same area. A region holding three
// readings or more is green, one or two pale, an empty one white; the targets are ringed.
function drawMap(s, targets) {
  const c = $("sphere"), g = c.getContext("2d");
  const a = { x0: 50, x1: c.width - 46, y0: 12, y1: c.height - 46 };
  const X = (lon) => a.x0 + (lon / 360) * (a.x1 - a.x0);
  const Y = (sinLat) => a.y0 + ((1 - sinLat) / 2) * (a.y1 - a.y0);
  g.clearRect(0, 0, c.width, c.height);
  drawMapRegions(g, s, X, Y);
  g.fillStyle = COLOUR.dot;
  for (const [lon, lat] of s.directions) g.fillRect(X(lon) - 1.5, Y(Math.sin(lat * DEG)) - 1.5, 3, 3);
  const newest = s.directions[s.directions.length - 1];
  if (newest) ring(g, X(newest[0]), Y(Math.sin(newest[1] * DEG)), 4.5, "#111", 2.5);
  drawMapTargets(g, targets, X, Y);
  drawMapAxes(g, a, X, Y);
  const gap = known(s.gap_percent) ? fmt(s.gap_percent, 1) + " %" : "-";
  text("gap", `MotionCal's gap error ${gap}; ${s.regions.filter((n) => n >= 3).length} of 100 regions hold three readings or more`);
}

// The regions, filled by the readings they hold.
function drawMapRegions(g, s, X, Y) {
  (s.region_bounds || []).forEach((r, k) => {
    const [red, green, blue] = regionColour(s.regions[k] || 0);
    g.fillStyle = `rgb(${red}, ${green}, ${blue})`;
    const x0 = X(360 * r.turn[0]), x1 = X(360 * r.turn[1]);
    const y0 = Y(r.sin_latitude[1]), y1 = Y(r.sin_latitude[0]);
    g.fillRect(x0, y0, x1 - x0, y1 - y0);
    g.strokeStyle = "#bbb";
    g.strokeRect(x0, y0, x1 - x0, y1 - y0);
  });
}

// The plan's targets on the map: the next a big red ring with a cross, the later small orange.
function drawMapTargets(g, targets, X, Y) {
  for (let k = targets.length - 1; k >= 0; k--) {
    if (!targets[k].field_direction) continue;
    const [lon, lat] = lonLatOf(targets[k].field_direction);
    const x = X(lon), y = Y(Math.sin(lat * DEG)), now = k === 0;
    ring(g, x, y, now ? 10 : 6, now ? COLOUR.now : COLOUR.later, now ? 3.5 : 2.5);
    if (now) {
      g.strokeStyle = COLOUR.now; g.lineWidth = 2;
      g.beginPath(); g.moveTo(x - 5, y); g.lineTo(x + 5, y); g.moveTo(x, y - 5); g.lineTo(x, y + 5); g.stroke();
      g.lineWidth = 1;
    }
  }
}

// The map's axes: longitude in degrees with the sensor's axes it passes (+x at 0, +y at 90, ...),
// the sine of latitude on the left and the latitude in degrees on the right.
function drawMapAxes(g, a, X, Y) {
  const axis = { 0: " (+x)", 90: " (+y)", 180: " (-x)", 270: " (-y)", 360: " (+x)" };
  const lons = [0, 45, 90, 135, 180, 225, 270, 315, 360].map((v) => [X(v), `${v}${axis[v] || ""}`]);
  const sines = [-1, -0.5, 0, 0.5, 1].map((v) => [Y(v), String(v)]);
  frameAxes(g, a, lons, sines, "longitude, deg (from x towards y)", "sine of latitude");
  g.textAlign = "left"; g.textBaseline = "middle"; g.font = "11px system-ui, sans-serif"; g.fillStyle = "#333";
  [[-90, -1], [-30, -0.5], [0, 0], [30, 0.5], [90, 1]].forEach(([lat, sine]) => g.fillText(`${lat}°`, a.x1 + 5, Y(sine)));
  g.fillText("+z", a.x1 + 30, Y(1)); g.fillText("-z", a.x1 + 30, Y(-1));
  verticalText(g, "latitude, deg (towards z)", a.x1 + 36, (a.y0 + a.y1) / 2);
  g.textAlign = "start"; g.textBaseline = "alphabetic";
}

/* ---------- Attitudes flown ---------- */

// Roll (x) against pitch (y) of the attitudes flown, the box, and the targets' roll and pitch
// (the next a big red ring, the later small orange).
function drawBox(s, targets) {
  const c = $("box"), g = c.getContext("2d");
  const r = s.roll_box || [-90, 90], p = s.pitch_box || [-90, 90];
  const span = (v) => [v[0] - 0.15 * (v[1] - v[0]) - 1, v[1] + 0.15 * (v[1] - v[0]) + 1];
  const [r0, r1] = span(r), [p0, p1] = span(p);
  const a = { x0: 50, x1: c.width - 12, y0: 24, y1: c.height - 46 };
  const X = (v) => a.x0 + ((v - r0) / (r1 - r0)) * (a.x1 - a.x0);
  const Y = (v) => a.y1 - ((v - p0) / (p1 - p0)) * (a.y1 - a.y0);
  g.clearRect(0, 0, c.width, c.height);
  g.strokeStyle = "#888"; g.setLineDash([4, 3]);
  g.strokeRect(X(r[0]), Y(p[1]), X(r[1]) - X(r[0]), Y(p[0]) - Y(p[1]));
  g.setLineDash([]);
  g.fillStyle = "#555"; g.font = "11px system-ui, sans-serif";
  const box = s.roll_box ? "the box" : "no box given";
  g.fillText(`${box}: roll ${fmt(r[0], 0)}..${fmt(r[1], 0)}, pitch ${fmt(p[0], 0)}..${fmt(p[1], 0)} deg`, a.x0, 15);
  if (s.attitudes.length === 0) none(g, (a.x0 + a.x1) / 2, (a.y0 + a.y1) / 2);
  g.fillStyle = COLOUR.flown;
  for (const [roll, pitch] of s.attitudes) g.fillRect(X(roll) - 1.5, Y(pitch) - 1.5, 3, 3);
  for (let k = targets.length - 1; k >= 0; k--) {
    const t = targets[k];
    if (!known(t.roll_deg) || !known(t.pitch_deg)) continue;
    ring(g, X(t.roll_deg), Y(t.pitch_deg), k === 0 ? 9 : 5, k === 0 ? COLOUR.now : COLOUR.later, k === 0 ? 3 : 2);
  }
  frameAxes(g, a, ticks(r0, r1, 6).map((v) => [X(v), String(v)]), ticks(p0, p1, 6).map((v) => [Y(v), String(v)]),
    "roll, deg (right side down)", "pitch, deg (nose up)");
}

// The note of a figure of attitudes when the stream carries none (lines of readings alone).
function none(g, x, y) {
  g.fillStyle = "#777"; g.font = "13px system-ui, sans-serif"; g.textAlign = "center";
  g.fillText("no attitudes in this stream", x, y);
  g.textAlign = "start";
}

// The heading a target asks for, magnetic where known, else true; null without one.
function headingOf(t) {
  return t ? (t.magnetic_heading_deg ?? t.true_heading_deg ?? null) : null;
}

// Headings flown (36 sectors of 10 degrees, north up, clockwise) and the next target's.
function drawHeadings(s, targets) {
  const c = $("headings"), g = c.getContext("2d"), w = c.width, h = c.height;
  const cx = w / 2, cy = h / 2, R = Math.min(w, h) / 2 - 22;
  const bins = new Array(36).fill(0);
  for (const a of s.attitudes) bins[Math.floor((((a[2] % 360) + 360) % 360) / 10) % 36] += 1;
  const most = Math.max(1, ...bins);
  g.clearRect(0, 0, w, h);
  g.strokeStyle = "#ccc";
  g.beginPath(); g.arc(cx, cy, R, 0, 2 * Math.PI); g.stroke();
  g.fillStyle = "#555"; g.font = "12px system-ui, sans-serif"; g.textAlign = "center"; g.textBaseline = "middle";
  [["N", 0], ["E", 90], ["S", 180], ["W", 270]].forEach(([name, hd]) => {
    const a = (hd - 90) * DEG;
    g.fillText(name, cx + (R + 11) * Math.cos(a), cy + (R + 11) * Math.sin(a));
  });
  g.textAlign = "start"; g.textBaseline = "alphabetic";
  if (s.attitudes.length === 0) none(g, cx, cy);
  g.fillStyle = COLOUR.flown;
  bins.forEach((n, k) => {
    if (n === 0) return;
    const a0 = (k * 10 - 90) * DEG, a1 = ((k + 1) * 10 - 90) * DEG;
    g.beginPath(); g.moveTo(cx, cy); g.arc(cx, cy, (R * n) / most, a0, a1); g.closePath(); g.fill();
  });
  const hd = headingOf(targets[0]);
  if (known(hd)) {
    const a = (hd - 90) * DEG;
    g.strokeStyle = COLOUR.now; g.lineWidth = 3;
    g.beginPath(); g.moveTo(cx, cy); g.lineTo(cx + R * Math.cos(a), cy + R * Math.sin(a)); g.stroke();
    g.lineWidth = 1;
  }
}

/* ---------- The verdict, the stream and the fit ---------- */

// The verdict line and the stream's counts.
function showVerdict(s) {
  text("source", s.source);
  const v = $("verdict");
  if (s.fit === 0) {
    v.className = "waiting"; text("verdict", "waiting for the first fit");
  } else if (s.usable) {
    v.className = "usable"; text("verdict", `USABLE for heading within ${fmt(s.heading_budget_deg, 1)} deg: ${fmt(s.heading_predicted_deg, 2)} deg predicted (fit ${s.fit}, ${s.readings} readings, ${s.model})`);
  } else {
    const heading = s.heading_predicted_deg === null ? "" : `heading ${fmt(s.heading_predicted_deg, 2)} of ${fmt(s.heading_budget_deg, 1)} deg; `;
    v.className = "unusable"; text("verdict", `not usable yet (fit ${s.fit}, ${s.readings} readings): ${heading}${s.reasons}`);
  }
  const kept = s.frames > 0 || s.lines === 0 ? `${s.frames} frames, ${s.bad_frames} bad` : `${s.lines} lines, ${s.malformed_lines} malformed, ${s.other_lines} other`;
  const quiet = s.quiet_s === null ? "nothing yet" : s.ended ? "ended" : `last bytes ${fmt(s.quiet_s, 1)} s ago`;
  text("stream", `${s.bytes} bytes: ${kept}; ${s.dropped_records} records dropped; ${quiet}; fit took ${fmt(s.fit_seconds, 2)} s`);
}

// The parameters with their standard errors, the set written and the export.
function showFit(s) {
  const body = $("fit").tBodies[0];
  body.replaceChildren();
  const u = s.units ? ` (${s.units})` : "";
  const rows = [["bias" + u, s.bias, s.bias_se, 4], ["scale", s.scale, s.scale_se, 5], ["psi (deg)", s.psi_deg, s.psi_se_deg, 3]];
  for (const [name, val, se, d] of rows) {
    const tr = body.insertRow();
    tr.insertCell().textContent = name;
    for (let k = 0; k < 3; k++) {
      tr.insertCell().textContent = val ? `${fmt(val[k], d)} ± ${se ? fmt(se[k], d) : "-"}` : "-";
    }
  }
  text("written", writtenWords(s));
  text("export", s.export || "");
}

function show(s) {
  const targets = targetsOf(s);
  // Once the budget is met the plan is no longer asked for: the figures drop its rings.
  const marked = s.done === true ? [] : targets;
  showVerdict(s);
  showGuidance(s, targets);
  updateGlobe(s, marked);
  drawMap(s, marked);
  drawBox(s, marked);
  drawHeadings(s, marked);
  showFit(s);
  text("updated", `updated ${new Date().toLocaleTimeString()}`);
}

async function poll() {
  try {
    const r = await fetch("/status.json", { cache: "no-store" });
    if (r.ok) show(await r.json());
  } catch (e) {
    text("updated", `magcal live is not answering (${e}); the last status is shown`);
  }
  setTimeout(poll, 500);
}

listenToGlobe();
requestAnimationFrame(frame);
poll();
