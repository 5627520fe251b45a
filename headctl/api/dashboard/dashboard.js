// headctl dashboard: polls /api/v1/state and /api/v1/learning, listens to /api/v1/events (SSE),
// shows both eyes' MJPEG streams and draws the learning curves on <canvas> by hand.
// No external resource: the head may have no internet.
"use strict";

(() => {
  const API = "/api/v1";
  const TOKEN = new URLSearchParams(location.search).get("token");
  const STATE_PERIOD_MS = 500;
  const LEARNING_PERIOD_MS = 1000;
  const MAX_POINTS = 20000;     // kept in the page (the server sends at most the last 5,000 at once)
  const MEAN_WINDOW = 10;       // the paper's figures: mean of the last 10 adaptations
  const MAX_EVENTS = 200;
  const EVENT_TYPES = ["saccade_onset", "saccade_done", "fixation_converged", "fixation_refused", "fault",
    "fault_cleared", "look_started", "look_done", "track_started", "track_lost", "track_stopped", "exploration",
    "torque", "map"];
  const JOINTS = ["pan", "tilt", "left_eye", "right_eye"];
  const COLORS = { pan: "#5b9bd5", tilt: "#e0a93b", vergence: "#c678dd", retinal: "#3fb27f", confidence: "#56b6c2" };

  const $ = (id) => document.getElementById(id);

  /** `path` with `params` and the page's token (if it was opened as /?token=...) as the query. */
  function withToken(path, params = {}) {
    const q = new URLSearchParams(params);
    if (TOKEN) q.set("token", TOKEN);
    const s = q.toString();
    return s ? `${path}?${s}` : path;
  }

  class ApiError extends Error {
    constructor(status, body) {
      const what = body && body.error
        ? body.error + (body.field ? ` (${body.field})` : "") + (body.reason ? `: ${body.reason}` : "")
        : `HTTP ${status}`;
      super(what);
      this.status = status;
      this.body = body;
    }
  }

  /** A JSON request; a service that does not answer within `timeoutMs` is an error, not a frozen page. */
  async function api(path, { method = "GET", body, params, timeoutMs = 5000 } = {}) {
    const abort = new AbortController();
    const timer = setTimeout(() => abort.abort(), timeoutMs);
    const init = { method, cache: "no-store", headers: { Accept: "application/json" }, signal: abort.signal };
    if (body !== undefined) {
      init.headers["Content-Type"] = "application/json";
      init.body = JSON.stringify(body);
    }
    try {
      const response = await fetch(withToken(API + path, params), init);
      let data = null;
      try { data = await response.json(); } catch (_) { /* not JSON */ }
      if (!response.ok) throw new ApiError(response.status, data);
      return data;
    } finally {
      clearTimeout(timer);
    }
  }

  // -- formatting --------------------------------------------------------------------------------
  const isNum = (x) => typeof x === "number" && Number.isFinite(x);
  const fmt = (x, digits = 2) => (isNum(x) ? x.toFixed(digits) : "–");
  const pct = (x, digits = 2) => (isNum(x) ? `${(x * 100).toFixed(digits)} %` : "–");

  function fmtDuration(s) {
    if (!isNum(s)) return "–";
    s = Math.floor(s);
    const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), sec = s % 60;
    return h ? `${h}h ${String(m).padStart(2, "0")}m` : m ? `${m}m ${String(sec).padStart(2, "0")}s` : `${sec}s`;
  }

  function fmtTime(unix) {
    if (!isNum(unix)) return "--:--:--";
    const d = new Date(unix * 1000);
    const p = (n, w = 2) => String(n).padStart(w, "0");
    return `${p(d.getHours())}:${p(d.getMinutes())}:${p(d.getSeconds())}.${p(d.getMilliseconds(), 3)}`;
  }

  function setBadge(el, state, text) {
    el.dataset.state = state;
    el.textContent = text === undefined ? state : text;
  }

  let messageTimer = null;
  function showMessage(text, isError = false) {
    const el = $("message");
    el.textContent = text;
    el.classList.toggle("error", isError);
    el.hidden = false;
    clearTimeout(messageTimer);
    messageTimer = setTimeout(() => { el.hidden = true; }, isError ? 10000 : 5000);
  }

  // -- the line plot ---------------------------------------------------------------------------------
  function niceStep(span, count) {
    const raw = span / Math.max(count, 1);
    const mag = Math.pow(10, Math.floor(Math.log10(raw)));
    const norm = raw / mag;
    return (norm < 1.5 ? 1 : norm < 3 ? 2 : norm < 7 ? 5 : 10) * mag;
  }

  function tickLabel(v) {
    if (v === 0) return "0";
    const a = Math.abs(v);
    if (a >= 1e5 || a < 1e-3) return v.toExponential(0);
    return String(Number(v.toPrecision(6)));
  }

  function linearTicks(lo, hi, count) {
    const step = niceStep(hi - lo, count);
    const ticks = [];
    for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) ticks.push(Math.abs(v) < step * 1e-9 ? 0 : v);
    return ticks;
  }

  // lo, hi: log10 of the range; pixels: the axis length. Labels at least ~22 px apart.
  function logTicks(lo, hi, pixels, count) {
    if (hi - lo < 0.6) {                 // less than a factor of 4: plain steps read better than decades
      return linearTicks(Math.pow(10, lo), Math.pow(10, hi), count).filter((v) => v > 0);
    }
    const ticks = [];
    const perDecade = pixels / (hi - lo);
    const mults = perDecade >= 150 ? [1, 2, 3, 5] : perDecade >= 75 ? [1, 2, 5] : perDecade >= 46 ? [1, 3] : [1];
    const every = Math.max(1, Math.ceil(22 / perDecade));   // decades between labels
    for (let e = Math.floor(lo); e <= Math.ceil(hi); e++) {
      if (e % every) continue;
      for (const m of mults) {
        const v = m * Math.pow(10, e);
        const l = Math.log10(v);
        if (l >= lo - 1e-9 && l <= hi + 1e-9) ticks.push(v);
      }
    }
    return ticks;
  }

  /**
   * A line plot on `canvas`: axes, ticks, labels, a legend, optionally a log y axis.
   * opts: {series: [{name, color, x: number[], y: number[], width?, alpha?, legend?}],
   *        xlabel, ylabel, log?, ymin?, ymax?, integerX?, empty?}
   * Non-finite values (and values <= 0 on a log axis) break the line. Returns the number of points drawn.
   */
  function linePlot(canvas, opts) {
    const dpr = window.devicePixelRatio || 1;
    const cssW = canvas.clientWidth, cssH = canvas.clientHeight;
    if (!cssW || !cssH) return 0;
    if (canvas.width !== Math.round(cssW * dpr) || canvas.height !== Math.round(cssH * dpr)) {
      canvas.width = Math.round(cssW * dpr);
      canvas.height = Math.round(cssH * dpr);
    }
    const ctx = canvas.getContext("2d");
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, cssW, cssH);
    const font = "11px system-ui, 'DejaVu Sans', sans-serif";
    ctx.font = font;
    const entries = opts.series.filter((s) => s.legend !== false && s.name);
    const m = { left: 50, right: 10, top: entries.length ? 20 : 8, bottom: 30 };   // the legend: a strip on top
    const pw = cssW - m.left - m.right, ph = cssH - m.top - m.bottom;
    const log = !!opts.log;
    const ty = (v) => (log ? (v > 0 ? Math.log10(v) : NaN) : v);

    let xlo = Infinity, xhi = -Infinity, ylo = Infinity, yhi = -Infinity, count = 0;
    for (const s of opts.series) {
      for (let i = 0; i < s.x.length; i++) {
        const x = s.x[i], y = ty(s.y[i]);
        if (!Number.isFinite(x) || !Number.isFinite(y)) continue;
        if (x < xlo) xlo = x;
        if (x > xhi) xhi = x;
        if (y < ylo) ylo = y;
        if (y > yhi) yhi = y;
        count++;
      }
    }
    if (isNum(opts.ymin) && !log) ylo = Math.min(ylo, opts.ymin);
    if (isNum(opts.ymax) && !log) yhi = Math.max(yhi, opts.ymax);

    // frame
    ctx.strokeStyle = "#3a4250";
    ctx.lineWidth = 1;
    ctx.strokeRect(m.left + 0.5, m.top + 0.5, pw, ph);
    ctx.fillStyle = "#8a93a3";
    ctx.textAlign = "center";
    ctx.textBaseline = "alphabetic";
    ctx.fillText(opts.xlabel || "", m.left + pw / 2, cssH - 3);
    ctx.save();
    ctx.translate(11, m.top + ph / 2);
    ctx.rotate(-Math.PI / 2);
    ctx.fillText((opts.ylabel || "") + (log ? " (log)" : ""), 0, 0);
    ctx.restore();
    if (!count) {
      ctx.fillText(opts.empty || "no data yet", m.left + pw / 2, m.top + ph / 2);
      return 0;
    }
    if (xhi === xlo) { xlo -= 1; xhi += 1; }
    if (yhi === ylo) { const d = log ? 0.5 : Math.abs(yhi) * 0.1 || 1; ylo -= d; yhi += d; }
    const pad = (yhi - ylo) * 0.05;
    if (!(isNum(opts.ymin) && !log && ylo === opts.ymin)) ylo -= pad;
    if (!(isNum(opts.ymax) && !log && yhi === opts.ymax)) yhi += pad;
    const X = (x) => m.left + ((x - xlo) / (xhi - xlo)) * pw;
    const Y = (y) => m.top + ph - ((y - ylo) / (yhi - ylo)) * ph;

    // grid and ticks
    ctx.textBaseline = "middle";
    ctx.textAlign = "right";
    const ycount = Math.max(2, Math.floor(ph / 35));
    const yt = log ? logTicks(ylo, yhi, ph, ycount) : linearTicks(ylo, yhi, ycount);
    for (const v of yt) {
      const py = Math.round(Y(ty(v))) + 0.5;
      ctx.strokeStyle = "#262c36";
      ctx.beginPath(); ctx.moveTo(m.left, py); ctx.lineTo(m.left + pw, py); ctx.stroke();
      ctx.strokeStyle = "#5a6372";
      ctx.beginPath(); ctx.moveTo(m.left - 4, py); ctx.lineTo(m.left, py); ctx.stroke();
      ctx.fillStyle = "#8a93a3";
      ctx.fillText(tickLabel(v), m.left - 6, py);
    }
    ctx.textAlign = "center";
    ctx.textBaseline = "top";
    for (const v of linearTicks(xlo, xhi, Math.max(2, Math.floor(pw / 60)))) {
      if (opts.integerX && !Number.isInteger(v)) continue;
      const px = Math.round(X(v)) + 0.5;
      ctx.strokeStyle = "#262c36";
      ctx.beginPath(); ctx.moveTo(px, m.top); ctx.lineTo(px, m.top + ph); ctx.stroke();
      ctx.strokeStyle = "#5a6372";
      ctx.beginPath(); ctx.moveTo(px, m.top + ph); ctx.lineTo(px, m.top + ph + 4); ctx.stroke();
      ctx.fillStyle = "#8a93a3";
      ctx.fillText(tickLabel(v), px, m.top + ph + 5);
    }

    // series, clipped to the frame; many points per pixel column are drawn as that column's min..max
    ctx.save();
    ctx.beginPath();
    ctx.rect(m.left, m.top, pw, ph);
    ctx.clip();
    for (const s of opts.series) {
      ctx.strokeStyle = s.color;
      ctx.globalAlpha = s.alpha === undefined ? 1 : s.alpha;
      ctx.lineWidth = s.width || 1.5;
      ctx.lineJoin = "round";
      ctx.beginPath();
      let pen = false, col = NaN, cmin = 0, cmax = 0;
      const flush = () => {
        if (!Number.isNaN(col) && cmax - cmin > 0.5) { ctx.lineTo(col, cmin); ctx.lineTo(col, cmax); }
      };
      for (let i = 0; i < s.x.length; i++) {
        const y = ty(s.y[i]);
        if (!Number.isFinite(s.x[i]) || !Number.isFinite(y)) { flush(); pen = false; col = NaN; continue; }
        const px = X(s.x[i]), py = Y(y), c = Math.round(px);
        if (pen && c === col) { cmin = Math.min(cmin, py); cmax = Math.max(cmax, py); continue; }
        flush();
        if (pen) ctx.lineTo(px, py); else ctx.moveTo(px, py);
        pen = true; col = c; cmin = cmax = py;
      }
      flush();
      if (s.x.length === 1) {   // a single point: a dot
        const y = ty(s.y[0]);
        if (Number.isFinite(y)) { ctx.fillStyle = s.color; ctx.fillRect(X(s.x[0]) - 2, Y(y) - 2, 4, 4); }
      }
      ctx.stroke();
    }
    ctx.restore();
    ctx.globalAlpha = 1;

    // legend: one row in the strip above the frame, right-aligned, never over the data
    if (entries.length) {
      ctx.font = font;
      ctx.textAlign = "left";
      ctx.textBaseline = "middle";
      const widths = entries.map((s) => ctx.measureText(s.name).width + 30);
      let lx = m.left + pw - widths.reduce((a, b) => a + b, 0) + 10;
      const ly = m.top / 2 + 1;
      entries.forEach((s, i) => {
        ctx.strokeStyle = s.color;
        ctx.globalAlpha = Math.max(0.5, s.alpha === undefined ? 1 : s.alpha);
        ctx.lineWidth = s.width || 1.5;
        ctx.beginPath(); ctx.moveTo(lx, ly); ctx.lineTo(lx + 14, ly); ctx.stroke();
        ctx.globalAlpha = 1;
        ctx.fillStyle = "#d7dce4";
        ctx.fillText(s.name, lx + 19, ly);
        lx += widths[i];
      });
    }
    return count;
  }

  // -- learning curves ---------------------------------------------------------------------------------
  const curve = { since: 0, n: [], retinal: [], pan: [], tilt: [], verg: [], conf: [],
    mean: { retinal: [], pan: [], tilt: [], verg: [], conf: [] } };

  function clearCurves() {
    for (const k of ["n", "retinal", "pan", "tilt", "verg", "conf"]) curve[k] = [];
    for (const k of Object.keys(curve.mean)) curve.mean[k] = [];
  }

  function trailingMean(values, i) {
    let sum = 0, k = 0;
    for (let j = Math.max(0, i - MEAN_WINDOW + 1); j <= i; j++) if (Number.isFinite(values[j])) { sum += values[j]; k++; }
    return k ? sum / k : NaN;
  }

  function addPoints(points) {
    for (const p of points) {
      const out = Array.isArray(p.output_error_deg) ? p.output_error_deg : [];
      const num = (v) => (isNum(v) ? v : NaN);
      // x: the map's adaptation count where the API gives it (continuous across a restart on a
      // restored map), else the point's index; a count going back is a new map, so a new curve
      const x = isNum(p.adaptations) ? p.adaptations : p.n;
      if (curve.n.length && x < curve.n[curve.n.length - 1]) clearCurves();
      curve.n.push(x);
      curve.retinal.push(isNum(p.retinal_error) ? p.retinal_error * 100 : NaN);
      curve.pan.push(num(out[0]));
      curve.tilt.push(num(out[1]));
      curve.verg.push(num(out[2]));
      curve.conf.push(num(p.confidence));
      const i = curve.n.length - 1;
      for (const k of Object.keys(curve.mean)) curve.mean[k].push(trailingMean(curve[k], i));
    }
    const extra = curve.n.length - MAX_POINTS;
    if (extra > 0) {
      for (const k of ["n", "retinal", "pan", "tilt", "verg", "conf"]) curve[k].splice(0, extra);
      for (const k of Object.keys(curve.mean)) curve.mean[k].splice(0, extra);
    }
  }

  function logScale(id) {
    const box = document.querySelector(`input[data-log="${id}"]`);
    return !!(box && box.checked);
  }

  function drawCurves() {
    const n = curve.n, mn = curve.mean;
    const plots = [
      ["curve-retinal", { xlabel: "adaptation", ylabel: "retinal error %", series: [
        { name: "each", color: COLORS.retinal, x: n, y: curve.retinal, width: 1, alpha: 0.3 },
        { name: `mean of last ${MEAN_WINDOW}`, color: COLORS.retinal, x: n, y: mn.retinal, width: 1.6 }] }],
      ["curve-output", { xlabel: `adaptation (bold: mean of last ${MEAN_WINDOW})`,
        ylabel: "output error °", series: [
        { name: "pan", color: COLORS.pan, x: n, y: curve.pan, width: 1, alpha: 0.18, legend: false },
        { name: "tilt", color: COLORS.tilt, x: n, y: curve.tilt, width: 1, alpha: 0.18, legend: false },
        { name: "vergence", color: COLORS.vergence, x: n, y: curve.verg, width: 1, alpha: 0.18, legend: false },
        { name: "pan", color: COLORS.pan, x: n, y: mn.pan, width: 1.6 },
        { name: "tilt", color: COLORS.tilt, x: n, y: mn.tilt, width: 1.6 },
        { name: "vergence", color: COLORS.vergence, x: n, y: mn.verg, width: 1.6 }] }],
      ["curve-confidence", { xlabel: "adaptation", ylabel: "confidence", ymin: 0, ymax: 1, series: [
        { name: "each", color: COLORS.confidence, x: n, y: curve.conf, width: 1, alpha: 0.3 },
        { name: `mean of last ${MEAN_WINDOW}`, color: COLORS.confidence, x: n, y: mn.conf, width: 1.6 }] }],
    ];
    for (const [id, opts] of plots) {
      const canvas = $(id);
      opts.log = logScale(id);
      opts.integerX = true;
      opts.empty = "waiting for the first adaptation";
      linePlot(canvas, opts);
      canvas.dataset.points = String(n.length);
    }
  }

  let drawPending = false;
  function scheduleDraw() {
    if (drawPending) return;
    drawPending = true;
    requestAnimationFrame(() => { drawPending = false; drawCurves(); });
  }

  async function pollLearning() {
    let data = null;
    try {
      data = await api("/learning", { params: { since: curve.since } });
    } catch (err) {
      // the state poll reports an unreachable service
    } finally {
      setTimeout(pollLearning, LEARNING_PERIOD_MS);   // runs after what follows (synchronous)
    }
    if (data === null) return;
    if (isNum(data.next) && data.next < curve.since) {
      curve.since = 0;               // the daemon restarted (its points count from 1 again): ask for all
      return;
    }
    addPoints(data.points || []);
    if (isNum(data.next)) curve.since = data.next;
    if ((data.points || []).length) scheduleDraw();
  }

  // -- the service's state -------------------------------------------------------------------------
  let stateGeneration = 0;     // bumped by every command, so a poll started before it cannot undo its result
  let lastState = null;

  const toggles = {
    explore: { button: "explore-toggle", badge: "explore-state", path: "/exploration", value: null, pending: false,
      what: "exploration" },
    torque: { button: "torque-toggle", badge: "torque-state", path: "/torque", value: null, pending: false,
      what: "torque", confirmOff: "Turn the servos' torque off? The head will no longer hold its pose." },
  };

  function renderToggle(t) {
    const button = $(t.button), badge = $(t.badge);
    if (t.value === null) {
      setBadge(badge, "unknown", "?");
      button.textContent = "…";
      button.disabled = true;
      delete button.dataset.enabled;
      return;
    }
    setBadge(badge, t.value ? "on" : "off");
    button.dataset.enabled = String(t.value);
    button.textContent = t.pending ? "…" : t.value ? "turn off" : "turn on";
    button.title = `${t.what} is ${t.value ? "on" : "off"}; click to turn it ${t.value ? "off" : "on"}`;
    button.disabled = t.pending;
  }

  async function flip(t) {
    if (t.value === null || t.pending) return;
    const want = !t.value;
    if (!want && t.confirmOff && !window.confirm(t.confirmOff)) return;
    t.pending = true;
    renderToggle(t);
    stateGeneration++;
    try {
      const r = await api(t.path, { method: "POST", body: { enabled: want } });
      if (typeof r.enabled === "boolean") t.value = r.enabled;
    } catch (err) {
      showMessage(`${t.what} ${want ? "on" : "off"} refused: ${err.message}`, true);
    } finally {
      t.pending = false;
      stateGeneration++;
      renderToggle(t);
      refreshState();
    }
  }

  function renderJoints(st) {
    const joints = st.joints || {};
    for (const name of JOINTS) {
      const j = joints[name];
      const row = document.querySelector(`#joints tr[data-joint="${name}"]`);
      const cell = (cls) => row.querySelector(`.${cls}`);
      const pos = $(`joint-${name}`);
      if (!j) {
        pos.textContent = "–";
        continue;
      }
      pos.textContent = fmt(j.position_deg, 2);
      pos.classList.toggle("moving", !!j.moving);
      cell("goal").textContent = fmt(j.goal_deg, 2);
      cell("vel").textContent = fmt(j.velocity_dps, 1);
      const tq = cell("torque");
      tq.textContent = j.torque_on ? "on" : "off";
      tq.classList.toggle("bad", !j.torque_on);
      cell("temp").textContent = fmt(j.temperature_c, 0);
      cell("volt").textContent = fmt(j.input_voltage_v, 1);
      const errs = j.hardware_errors || [];
      const he = cell("hwerr");
      he.textContent = errs.length ? errs.join(", ") : "none";
      he.classList.toggle("bad", errs.length > 0);
    }
    const pose = st.pose || {};
    $("pose-pan").textContent = fmt(pose.pan, 2);
    $("pose-tilt").textContent = fmt(pose.tilt, 2);
    $("vergence").textContent = fmt(pose.vergence, 2);
    const sl = st.servo_loop;
    $("servo-loop").textContent = sl
      ? `servo loop ${fmt(sl.rate_hz, 0)} Hz · period p99 ${fmt(sl.period_p99_ms, 2)} ms · jitter p99 ${fmt(sl.jitter_p99_ms, 2)} ms`
        + ` · overruns ${sl.overruns ?? "–"} · read errors ${sl.read_errors ?? "–"}`
      : "servo loop –";
  }

  function renderFixation(st) {
    const fx = st.fixation || {};
    $("fixation-state").textContent = fx.state || "–";
    $("fix-done").textContent = fx.done ?? "–";
    $("fix-taught").textContent = fx.taught ?? "–";
    const refused = Object.entries(fx.refused || {}).sort((a, b) => b[1] - a[1]);
    $("fix-refused").textContent = refused.reduce((s, [, c]) => s + c, 0);
    const list = $("refused");
    list.replaceChildren(...refused.map(([reason, count]) => {
      const li = document.createElement("li");
      const span = document.createElement("span");
      span.textContent = reason;
      const b = document.createElement("b");
      b.textContent = count;
      li.append(span, b);
      return li;
    }));
    const ln = st.learning || {};
    $("adaptations").textContent = ln.adaptations ?? "–";
    $("mean-retinal").textContent = pct(ln.mean_retinal_error);
    const oe = ln.output_error_deg;
    $("output-error").textContent = Array.isArray(oe)
      ? ["pan", "tilt", "verg"].map((axis, i) => `${axis} ${fmt(oe[i], 2)}`).join(" · ") : "–";
    const last = fx.last;
    if (last) {
      const parts = [`last #${last.index}`];
      if (last.kind) parts.push(last.kind);
      parts.push(last.outcome);
      if (isNum(last.duration_s)) parts.push(`${fmt(last.duration_s, 2)} s`);
      if (isNum(last.confidence)) parts.push(`conf ${fmt(last.confidence, 2)}`);
      if (Array.isArray(last.position)) parts.push(`at (${last.position.map((v) => fmt(v, 1)).join(", ")})`);
      $("fix-last").textContent = parts.join(" · ") + (last.detail ? ` — ${last.detail}` : "");
    } else {
      $("fix-last").textContent = "last: –";
    }
    const lat = fx.vergence_latency_ms, mp = st.map;
    const extra = [];
    if (lat && isNum(lat.p50)) extra.push(`vergence latency p50 ${fmt(lat.p50, 0)} ms, p99 ${fmt(lat.p99, 0)} ms`);
    if (mp) {
      extra.push(`map: ${mp.checkpoints ?? 0} checkpoints`
        + (isNum(mp.last_checkpoint_adaptations) && mp.last_checkpoint_adaptations >= 0
          ? `, last at ${mp.last_checkpoint_adaptations} adaptations` : "")
        + (mp.restored_from ? `, restored from ${mp.restored_from}` : ""));
    }
    $("fix-more").textContent = extra.join(" · ");
  }

  function listItem(text, className = "") {
    const li = document.createElement("li");
    li.className = className;
    li.textContent = text;
    return li;
  }

  function renderFaults(st) {
    const faults = st.faults || [];
    $("faults").replaceChildren(...(faults.length ? faults.map((f) => listItem(f)) : [listItem("none", "none")]));
    setBadge($("fault-count"), faults.length ? "bad" : "ok", String(faults.length));
  }

  let logKey = null;
  function renderLog(st) {
    const lines = (st.events || []).slice(-MAX_EVENTS).reverse();
    const key = lines.length ? `${lines.length}:${lines[0].time}:${lines[0].message}` : "";
    if (key === logKey) return;       // unchanged: keep the reader's scroll position
    logKey = key;
    const ul = $("log");
    ul.replaceChildren(...(lines.length
      ? lines.map((e) => eventItem(e.time, e.level, `${e.logger}: ${e.message}`))
      : [listItem("no warnings", "muted")]));
  }

  function renderEyes(st) {
    const size = st.image_size;
    const cams = st.cameras || {};
    for (const side of ["left", "right"]) {
      const img = $(`eye-${side}`);
      if (Array.isArray(size) && size[0] > 0 && size[1] > 0) img.style.aspectRatio = `${size[0]} / ${size[1]}`;
      const cam = cams[side];
      const bits = [side === "left" ? "left eye (click: look there)" : "right eye"];
      if (Array.isArray(size)) bits.push(`${size[0]} × ${size[1]}`);
      if (cam && cam.health) bits.push(cam.health);
      if (cam && isNum(cam.frame_age_s)) bits.push(`frame age ${fmt(cam.frame_age_s * 1000, 0)} ms`);
      img.parentElement.querySelector("figcaption").textContent = bits.join(" · ");
    }
  }

  function render(st) {
    // A stream that the server ended (a restart) does not error in an <img>: reconnect both eyes
    // whenever the service comes back or is a new process.
    const restarted = lastState !== null && (st.pid !== lastState.pid || st.uptime_s < lastState.uptime_s);
    if (restarted || serviceLost) connectEyes(true);
    if (restarted) curve.since = 0;       // a new process numbers its learning points from 1 again
    serviceLost = false;
    lastState = st;
    setBadge($("service-state"), st.state || "unknown");
    $("uptime").textContent = fmtDuration(st.uptime_s);
    toggles.explore.value = st.fixation && typeof st.fixation.explore === "boolean" ? st.fixation.explore : null;
    let torque = typeof st.torque === "boolean" ? st.torque : null;
    if (torque === null && st.joints && Object.keys(st.joints).length) {
      torque = Object.values(st.joints).every((j) => j.torque_on);
    }
    toggles.torque.value = torque;
    for (const t of Object.values(toggles)) if (!t.pending) renderToggle(t);
    renderJoints(st);
    renderFixation(st);
    renderFaults(st);
    renderLog(st);
    renderEyes(st);
  }

  let stateTimer = null;
  let stateInFlight = false;
  let serviceLost = false;
  async function refreshState() {
    clearTimeout(stateTimer);
    if (stateInFlight) { stateTimer = setTimeout(refreshState, 50); return; }
    stateInFlight = true;
    const generation = stateGeneration;
    let delay = STATE_PERIOD_MS;
    let st = null;
    try {
      st = await api("/state");
    } catch (err) {
      setBadge($("service-state"), "unreachable", err.status ? `error ${err.status}` : "unreachable");
      serviceLost = true;
      if (err.status === 401 || err.status === 403) {
        showMessage(`the API refused this page (${err.message}): open it as /?token=…`, true);
      }
      delay = 2000;
    } finally {
      stateInFlight = false;
      stateTimer = setTimeout(refreshState, delay);
    }
    if (st !== null && generation === stateGeneration) render(st);   // a bug here reaches the console
  }

  // -- events (SSE) ------------------------------------------------------------------------------------
  function eventItem(time, kind, text) {
    const li = document.createElement("li");
    const t = document.createElement("span");
    t.className = "t";
    t.textContent = fmtTime(time);
    const k = document.createElement("span");
    k.className = `k ${kind}`;
    k.textContent = kind;
    li.append(t, k, document.createTextNode(text));
    li.title = `${fmtTime(time)} ${kind} ${text}`;
    return li;
  }

  function summary(data) {
    return Object.entries(data)
      .filter(([k, v]) => !["seq", "time", "type"].includes(k) && v !== "" && v !== null)
      .map(([k, v]) => {
        if (isNum(v)) return `${k}=${Number.isInteger(v) ? v : v.toFixed(3)}`;
        if (Array.isArray(v)) return `${k}=[${v.map((x) => (isNum(x) ? +x.toFixed(2) : x)).join(", ")}]`;
        if (v && typeof v === "object") return `${k}=${JSON.stringify(v)}`;
        return `${k}=${v}`;
      })
      .join(" ");
  }

  const REFRESH_ON = new Set(["exploration", "torque", "fault", "fault_cleared", "map"]);

  // The stream is opened with ?after=0, so that the page starts with the server's recent events;
  // a reconnect replays them: an event no newer (seq and time) than the last one shown is skipped.
  // A restarted daemon numbers from 1 again, but its events are newer.
  let lastSeq = 0, lastTime = 0;

  function onEvent(type, raw) {
    let data;
    try { data = JSON.parse(raw); } catch (_) { data = { message: raw }; }
    if (isNum(data.seq) && isNum(data.time)) {
      if (data.seq <= lastSeq && data.time <= lastTime) return;
      lastSeq = data.seq;
      lastTime = data.time;
    }
    const ul = $("events");
    const placeholder = ul.querySelector(".placeholder");
    if (placeholder) placeholder.remove();
    ul.prepend(eventItem(isNum(data.time) ? data.time : Date.now() / 1000, type, summary(data)));
    while (ul.children.length > MAX_EVENTS) ul.lastElementChild.remove();
    ul.dataset.count = String(Number(ul.dataset.count || 0) + 1);
    if (REFRESH_ON.has(type)) refreshState();
    if (type === "look_done") onLookDone(data);
    if (type.startsWith("track_")) onTrackEvent(type, data);
  }

  function connectEvents() {
    const es = new EventSource(withToken(`${API}/events`, { after: 0 }));
    const badge = $("stream-state");
    setBadge(badge, "reconnecting", "connecting");
    es.onopen = () => setBadge(badge, "open", "live");
    es.onerror = () => {
      if (es.readyState === EventSource.CLOSED) {    // refused (not a dropped connection): retry later ourselves
        setBadge(badge, "failed", "closed");
        es.close();
        setTimeout(connectEvents, 5000);
      } else {
        setBadge(badge, "reconnecting");
      }
    };
    for (const type of EVENT_TYPES) es.addEventListener(type, (e) => onEvent(type, e.data));
    // the server dropped events this page did not read in time
    es.addEventListener("lost", (e) => onEvent("lost", e.data));
  }

  // -- the eyes -------------------------------------------------------------------------------------------
  const eyeRetry = {};
  function connectEyes(fresh) {
    for (const side of ["left", "right"]) {
      clearTimeout(eyeRetry[side]);
      $(`eye-${side}`).src = withToken(`${API}/eyes/${side}.mjpg`, fresh ? { t: Date.now() } : {});
    }
  }

  function watchEyes() {
    for (const side of ["left", "right"]) {
      $(`eye-${side}`).onerror = () => {     // refused or unreachable: try again in a while
        clearTimeout(eyeRetry[side]);
        eyeRetry[side] = setTimeout(() => {
          $(`eye-${side}`).src = withToken(`${API}/eyes/${side}.mjpg`, { t: Date.now() });
        }, 2000);
      };
    }
  }

  // -- looking where the user clicks ---------------------------------------------------------------------
  let clickedLook = null;     // the id of the look sent by the last click, its end shown when it comes

  /** A click on the left eye: look at that pixel, the disparity measured there by the daemon
   *  (`replace`: the newest click wins over a look still running). */
  async function lookAtClick(event) {
    const img = event.currentTarget;
    if (!img.naturalWidth || !img.naturalHeight) return;
    const rect = img.getBoundingClientRect();
    // object-fit: contain may letterbox the frame inside the element
    const scale = Math.min(rect.width / img.naturalWidth, rect.height / img.naturalHeight);
    const left = rect.left + (rect.width - img.naturalWidth * scale) / 2;
    const top = rect.top + (rect.height - img.naturalHeight * scale) / 2;
    // frame pixels to image pixels (the stream may be sent smaller than the cameras' images)
    const size = lastState && Array.isArray(lastState.image_size) ? lastState.image_size : [img.naturalWidth, img.naturalHeight];
    const x = ((event.clientX - left) / scale) * (size[0] / img.naturalWidth);
    const y = ((event.clientY - top) / scale) * (size[1] / img.naturalHeight);
    if (x < 0 || y < 0 || x > size[0] - 1 || y > size[1] - 1) return;
    const at = { x: Math.round(x * 10) / 10, y: Math.round(y * 10) / 10 };
    img.dataset.clickX = String(at.x);
    img.dataset.clickY = String(at.y);
    if (event.shiftKey || $("track-mode").checked) return trackAt(at);
    try {
      const job = await api("/look/target", { method: "POST", body: { ...at, replace: true } });
      const r = job.request;
      clickedLook = job.id;
      img.dataset.look = String(job.id);
      showMessage(`look ${job.id} at x ${fmt(r.x, 1)}, y ${fmt(r.y, 1)}: d ${fmt(r.d, 2)} px ` +
                  `(measured, NCC ${fmt(r.d_ncc, 2)}), ${job.state}`);
    } catch (err) {
      showMessage(`no look at x ${at.x}, y ${at.y}: ${err.message}`, true);
    }
  }

  // -- tracking (smooth pursuit) where the user clicks with shift, or with the track switch on ------------
  let trackId = null;         // the track started from this page, while it runs

  async function trackAt(at) {
    try {
      const job = await api("/track", { method: "POST", body: at });
      trackId = job.id;
      $("eye-left").dataset.track = String(job.id);
      $("track-stop").hidden = false;
      $("track-state").textContent = `track ${job.id} at x ${fmt(at.x, 1)}, y ${fmt(at.y, 1)}: ${job.state}`;
    } catch (err) {
      showMessage(`no track at x ${at.x}, y ${at.y}: ${err.message}`, true);
    }
  }

  async function stopTrack() {
    try {
      await api("/track", { method: "DELETE", params: { wait_s: 2 } });
    } catch (err) {
      showMessage(`stop tracking: ${err.message}`, true);
    }
  }

  function onTrackEvent(type, data) {
    if (type === "track_started") {
      $("track-state").textContent = `tracking (track ${data.id}): the patch is marked in magenta`;
      $("track-stop").hidden = false;
      return;
    }
    $("track-state").textContent = `track ${data.id} ${type === "track_lost" ? "lost" : data.outcome}` +
      (data.detail ? ` (${data.detail})` : "");
    if (data.id === trackId) trackId = null;
    $("track-stop").hidden = true;
  }

  function onLookDone(data) {
    if (data.id !== clickedLook) return;
    const how = [data.outcome, data.detail].filter(Boolean).join(": ");
    showMessage(`look ${data.id} ${data.state}${how ? ` (${how})` : ""}`, data.state !== "done");
  }

  // -- start ---------------------------------------------------------------------------------------------
  function start() {
    const events = $("events");
    events.replaceChildren(listItem("waiting for events", "placeholder muted"));
    events.dataset.count = "0";
    for (const t of Object.values(toggles)) {
      renderToggle(t);
      $(t.button).addEventListener("click", () => flip(t));
    }
    $("map-save").addEventListener("click", async () => {
      const button = $("map-save");
      button.disabled = true;
      try {
        const r = await api("/map/save", { method: "POST", body: {}, timeoutMs: 30000 });
        showMessage(`map saved: ${r.path} (${r.adaptations} adaptations)`);
      } catch (err) {
        showMessage(`map save failed: ${err.message}`, true);
      } finally {
        button.disabled = false;
      }
    });
    for (const box of document.querySelectorAll("input[data-log]")) box.addEventListener("change", scheduleDraw);
    window.addEventListener("resize", scheduleDraw);
    watchEyes();
    $("eye-left").addEventListener("click", lookAtClick);
    $("track-stop").addEventListener("click", stopTrack);
    // The streams start after the page's load event: an endless multipart image must not keep the
    // page loading (a browser's spinner, or a test waiting for the load to finish).
    if (document.readyState === "complete") connectEyes(false);
    else window.addEventListener("load", () => connectEyes(false), { once: true });
    connectEvents();
    refreshState();
    pollLearning();
    scheduleDraw();
  }

  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start);
  else start();
})();
