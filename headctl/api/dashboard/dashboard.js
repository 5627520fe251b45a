// headctl dashboard: polls /api/v1/state and /api/v1/learning, listens to /api/v1/events (SSE),
// shows both eyes' MJPEG streams and the learning curves, charted by uPlot (vendor/, served with
// the page). No external resource: the head may have no internet.
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

  // -- the curves' charts: uPlot (vendor/uPlot.iife.min.js, MIT) ---------------------------------------
  const CHART_HEIGHT = 175;
  const AXIS = { stroke: "#8a93a3", grid: { stroke: "#262c36", width: 1 }, ticks: { stroke: "#5a6372", width: 1 },
    font: "11px system-ui, 'DejaVu Sans', sans-serif", labelFont: "11px system-ui, 'DejaVu Sans', sans-serif" };
  const EACH = 0.3, EACH_AXIS = 0.18;   // the faint lines of each adaptation under the means

  /** A series: `alpha` < 1 for each adaptation's value (thin, faint), 1 for a mean (bold); no
   *  label: not in the legend (its row's class hides it). */
  function line(label, color, alpha = 1) {
    const a = Math.round(alpha * 255).toString(16).padStart(2, "0");
    return { label: label || " ", class: label ? undefined : "unlisted", stroke: color + a, width: alpha < 1 ? 1 : 1.6,
      points: { show: false } };
  }

  const mean = `mean of last ${MEAN_WINDOW}`;
  const CHARTS = {
    "curve-retinal": { ylabel: "retinal error %",
      series: [line("each", COLORS.retinal, EACH), line(mean, COLORS.retinal)],
      data: () => [curve.retinal, curve.mean.retinal] },
    "curve-output": { ylabel: "output error °", xlabel: `adaptation (bold: ${mean})`,
      series: [line("", COLORS.pan, EACH_AXIS), line("", COLORS.tilt, EACH_AXIS), line("", COLORS.vergence, EACH_AXIS),
        line("pan", COLORS.pan), line("tilt", COLORS.tilt), line("vergence", COLORS.vergence)],
      data: () => [curve.pan, curve.tilt, curve.verg, curve.mean.pan, curve.mean.tilt, curve.mean.verg] },
    "curve-confidence": { ylabel: "confidence", range: (u, lo, hi) => [Math.min(0, lo), Math.max(1, hi)],
      series: [line("each", COLORS.confidence, EACH), line(mean, COLORS.confidence)],
      data: () => [curve.conf, curve.mean.conf] },
  };
  const charts = {};    // id -> uPlot; made again when its log switch changes
  // a log axis: grid lines and ticks at the decades only (uPlot splits every 1..9 of each)
  const decades = (u, splits) => splits.map((v) => (Math.abs(Math.log10(v) % 1) < 1e-9 ? v : null));

  /** The chart's columns: x, then each series; what a line cannot show (non-finite, or <= 0 on a log axis) breaks it. */
  function columns(id, log) {
    const keep = log ? (v) => (v > 0 ? v : null) : (v) => (Number.isFinite(v) ? v : null);
    return [curve.n, ...CHARTS[id].data().map((ys) => ys.map(keep))];
  }

  function makeChart(id) {
    const spec = CHARTS[id], el = $(id), log = logScale(id);
    if (charts[id]) charts[id].destroy();
    charts[id] = new uPlot({
      width: el.clientWidth || 300, height: CHART_HEIGHT,
      scales: { x: { time: false }, y: log ? { distr: 3 } : { range: spec.range } },
      axes: [{ ...AXIS, label: spec.xlabel || "adaptation" },
        { ...AXIS, label: spec.ylabel + (log ? " (log)" : ""), size: 55,
          ...(log ? { grid: { ...AXIS.grid, filter: decades }, ticks: { ...AXIS.ticks, filter: decades } } : {}) }],
      series: [{ label: "adaptation" }, ...spec.series],
      legend: { live: false },
    }, columns(id, log), el);
  }

  function drawCurves() {
    for (const id of Object.keys(CHARTS)) {
      const el = $(id);
      if (!charts[id]) makeChart(id);
      const chart = charts[id];
      if (el.clientWidth && chart.width !== el.clientWidth) chart.setSize({ width: el.clientWidth, height: CHART_HEIGHT });
      chart.setData(columns(id, logScale(id)));
      el.dataset.points = String(curve.n.length);
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
    // A simulated head's world (ideal, realistic or mixed), its parts in the tooltip.
    $("world").hidden = !st.world;
    if (st.world) {
      $("world-kind").textContent = st.world.kind;
      $("world-kind").dataset.state = st.world.kind;
      $("world").title = st.world.text;
    }
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
    for (const box of document.querySelectorAll("input[data-log]")) {
      box.addEventListener("change", () => { makeChart(box.dataset.log); scheduleDraw(); });
    }
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
