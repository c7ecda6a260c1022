// magcal live: polls /status.json and draws the fit, the coverage and the next attitude.
"use strict";

const $ = (id) => document.getElementById(id);
// A number to d decimals; a negative number that rounds to zero is shown without its sign.
const fmt = (v, d) => {
  if (v === null || v === undefined) return "-";
  const t = Number(v).toFixed(d);
  return /^-0(\.0*)?$/.test(t) ? t.slice(1) : t;
};

function text(id, s) {
  $(id).textContent = s;
}

// Calibrated directions on MotionCal's 100 equal-area regions: longitude (x, 0 to 360 degrees
// from the sensor's x axis towards its y axis) against the sine of the latitude (y, towards z),
// a projection in which every region is a rectangle of the same area. A region holding three
// readings or more is green, one or two pale; an empty one white.
function drawSphere(s) {
  const c = $("sphere"), g = c.getContext("2d"), w = c.width, h = c.height;
  const X = (lon) => (lon / 360) * w, Y = (sinLat) => ((1 - sinLat) / 2) * h;
  g.clearRect(0, 0, w, h);
  s.region_bounds.forEach((r, k) => {
    const n = s.regions[k] || 0;
    g.fillStyle = n >= 3 ? "#9fd69f" : n > 0 ? "#e3f2e3" : "#ffffff";
    const x0 = X(360 * r.turn[0]), x1 = X(360 * r.turn[1]);
    const y0 = Y(r.sin_latitude[1]), y1 = Y(r.sin_latitude[0]);
    g.fillRect(x0, y0, x1 - x0, y1 - y0);
    g.strokeStyle = "#bbb";
    g.strokeRect(x0, y0, x1 - x0, y1 - y0);
  });
  g.fillStyle = "#1f4e9c";
  for (const [lon, lat] of s.directions) {
    g.fillRect(X(lon) - 1.5, Y(Math.sin((lat * Math.PI) / 180)) - 1.5, 3, 3);
  }
  const gap = s.gap_percent === null || s.gap_percent === undefined ? "-" : fmt(s.gap_percent, 1) + " %";
  text("gap", `MotionCal's gap error ${gap}; ${s.regions.filter((n) => n >= 3).length} of 100 regions hold three readings or more`);
}

// Roll (x) against pitch (y) of the attitudes flown, the box, and the next attitude.
function drawBox(s) {
  const c = $("box"), g = c.getContext("2d"), w = c.width, h = c.height;
  const r = s.roll_box || [-90, 90], p = s.pitch_box || [-90, 90];
  const span = (a) => [a[0] - 0.15 * (a[1] - a[0]) - 1, a[1] + 0.15 * (a[1] - a[0]) + 1];
  const [r0, r1] = span(r), [p0, p1] = span(p);
  const X = (v) => ((v - r0) / (r1 - r0)) * w, Y = (v) => h - ((v - p0) / (p1 - p0)) * h;
  g.clearRect(0, 0, w, h);
  g.strokeStyle = "#888";
  g.strokeRect(X(r[0]), Y(p[1]), X(r[1]) - X(r[0]), Y(p[0]) - Y(p[1]));
  g.fillStyle = "#555";
  g.fillText(`roll ${fmt(r[0], 0)}..${fmt(r[1], 0)}, pitch ${fmt(p[0], 0)}..${fmt(p[1], 0)} deg`, 6, 14);
  g.fillStyle = "#2ca02c";
  for (const [roll, pitch] of s.attitudes) g.fillRect(X(roll) - 1.5, Y(pitch) - 1.5, 3, 3);
  if (s.next) {
    g.strokeStyle = "#d62728"; g.lineWidth = 3;
    g.beginPath(); g.arc(X(s.next.roll_deg), Y(s.next.pitch_deg), 9, 0, 2 * Math.PI); g.stroke();
    g.lineWidth = 1;
  }
}

// Headings flown (36 sectors of 10 degrees, north up, clockwise) and the next one.
function drawHeadings(s) {
  const c = $("headings"), g = c.getContext("2d"), w = c.width, h = c.height;
  const cx = w / 2, cy = h / 2, R = Math.min(w, h) / 2 - 14;
  const bins = new Array(36).fill(0);
  for (const a of s.attitudes) bins[Math.floor((((a[2] % 360) + 360) % 360) / 10) % 36] += 1;
  const most = Math.max(1, ...bins);
  g.clearRect(0, 0, w, h);
  g.strokeStyle = "#ccc";
  g.beginPath(); g.arc(cx, cy, R, 0, 2 * Math.PI); g.stroke();
  g.fillStyle = "#555"; g.fillText("N", cx - 3, 11);
  g.fillStyle = "#2ca02c";
  bins.forEach((n, k) => {
    if (n === 0) return;
    const a0 = ((k * 10 - 90) * Math.PI) / 180, a1 = (((k + 1) * 10 - 90) * Math.PI) / 180;
    g.beginPath(); g.moveTo(cx, cy); g.arc(cx, cy, (R * n) / most, a0, a1); g.closePath(); g.fill();
  });
  if (s.next) {
    const hd = s.next.magnetic_heading_deg ?? s.next.true_heading_deg;
    const a = ((hd - 90) * Math.PI) / 180;
    g.strokeStyle = "#d62728"; g.lineWidth = 3;
    g.beginPath(); g.moveTo(cx, cy); g.lineTo(cx + R * Math.cos(a), cy + R * Math.sin(a)); g.stroke();
    g.lineWidth = 1;
  }
}

function show(s) {
  text("source", s.source);
  const v = $("verdict");
  if (s.fit === 0) {
    v.className = "waiting"; v.textContent = "waiting for the first fit";
  } else if (s.usable) {
    v.className = "usable"; v.textContent = `USABLE for heading within ${fmt(s.heading_budget_deg, 1)} deg: ${fmt(s.heading_predicted_deg, 2)} deg predicted (fit ${s.fit}, ${s.readings} readings, ${s.model})`;
  } else {
    const heading = s.heading_predicted_deg === null ? "" : `heading ${fmt(s.heading_predicted_deg, 2)} of ${fmt(s.heading_budget_deg, 1)} deg; `;
    v.className = "unusable"; v.textContent = `not usable yet (fit ${s.fit}, ${s.readings} readings): ${heading}${s.reasons}`;
  }
  const kept = s.frames > 0 || s.lines === 0 ? `${s.frames} frames, ${s.bad_frames} bad` : `${s.lines} lines, ${s.malformed_lines} malformed, ${s.other_lines} other`;
  const quiet = s.quiet_s === null ? "nothing yet" : s.ended ? "ended" : `last bytes ${fmt(s.quiet_s, 1)} s ago`;
  text("stream", `${s.bytes} bytes: ${kept}; ${s.dropped_records} records dropped; ${quiet}; fit took ${fmt(s.fit_seconds, 2)} s`);
  if (s.next) {
    const m = s.next.magnetic_heading_deg;
    const heading = m === null ? `true heading ${fmt(s.next.true_heading_deg, 0)}` : `magnetic heading ${fmt(m, 0)} (true ${fmt(s.next.true_heading_deg, 0)})`;
    text("next", `roll ${fmt(s.next.roll_deg, 0)}, pitch ${fmt(s.next.pitch_deg, 0)}, ${heading} deg`);
  } else if (s.next_error) {
    text("next", s.next_error);
  }
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
  text("written", s.written_fit === null ? `nothing written to ${s.out} yet` : `${s.out} holds fit ${s.written_fit} (${s.written_usable ? "usable" : "not usable"})`);
  text("export", s.export || "");
  drawSphere(s);
  drawBox(s);
  drawHeadings(s);
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

poll();
