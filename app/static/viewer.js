// undertow plan viewer: load or paste a scene, edit the robot and its waves, plan it through
// the HTTP API, and watch the result: the arm (with each active link's mass path r(q) e(q)),
// the torques, sigma_min(M_pa) with and without the waves, and the joint angles.
// Plain browser JavaScript, no dependencies. Model convention: x along gravity (drawn
// downwards), y to the right; e(q) = (cos q, sin q).
"use strict";

(() => {
  const $ = (id) => document.getElementById(id);
  const KEY_STORE = "undertow.apiKey";
  const FINAL = new Set(["succeeded", "failed", "cancelled"]);
  const POLL_MS = 250;
  const SIGMA_FLOOR = 1e-12;
  // the figures' colours (planner.plots.PALETTE, served as /palette.js): one palette for both
  const PALETTE = window.UNDERTOW_PALETTE;
  const COLORS = PALETTE.joints;
  const C = { ink: "#1d2733", muted: "#8a94a0", grid: "#eef1f5", active: PALETTE.active,
              passive: PALETTE.passive, with: PALETTE.with, without: PALETTE.without, mark: PALETTE.mark };

  const START_CAPTION = "The scene's arm at its start (task.initial.q), each active link's " +
    "mass path faint; plan the scene to see it move. Gravity (x) points down.";

  const state = {
    scene: null,        // the scene being edited (JSON object)
    submitted: null,    // the scene of the latest job
    job: null,          // the latest job from the server
    plan: null,         // its plan
    robot: null,        // the scene's robot with the plan's waves
    frames: null,       // per dense sample: joint positions (n + 1) x 2, model coordinates
    sigma: null,        // { with: [], without: [] } at plan.dense.t (the plan's own), or { note }
    t: 0, playing: false, lastTick: null, pollTimer: null, plots: [],
  };

  // ------------------------------------------------------------------ HTTP

  class Problem extends Error {
    constructor(status, body) {
      super(body.detail || body.title || `HTTP ${status}`);
      this.status = status;
      this.body = body;
    }
  }

  async function api(path, options = {}) {
    const headers = { Accept: "application/json, application/problem+json" };
    if (options.body !== undefined) headers["Content-Type"] = "application/json";
    const key = localStorage.getItem(KEY_STORE);
    if (key) headers["X-API-Key"] = key;
    let response;
    try {
      response = await fetch(path, { ...options, headers });
    } catch (err) {
      throw new Problem(0, { title: "The server cannot be reached", detail: String(err) });
    }
    if (response.status === 401) showKeyForm();
    if (options.raw && response.ok) return response.blob();
    const text = await response.text();
    let body = null;
    try { body = text ? JSON.parse(text) : null; } catch (_) { body = null; }
    if (!response.ok) {
      throw new Problem(response.status, body && typeof body === "object" ? body
        : { title: `HTTP ${response.status}`, detail: text.slice(0, 300) });
    }
    return body;
  }

  // ------------------------------------------------------------------ messages

  function showError(err, context) {
    const box = $("error");
    box.replaceChildren();
    const head = document.createElement("strong");
    const body = err instanceof Problem ? err.body : { title: String(err) };
    head.textContent = (context ? context + ": " : "") + (body.title || "Error") +
      (err.status ? ` (${err.status})` : "");
    box.append(head);
    if (body.detail) box.append(document.createTextNode(body.detail));
    if (Array.isArray(body.errors) && body.errors.length) {
      const list = document.createElement("ul");
      for (const e of body.errors) {
        const item = document.createElement("li");
        const where = document.createElement("code");
        where.textContent = e.loc.filter((p) => p !== "body").join(".");
        item.append(where, document.createTextNode(" " + e.msg));
        list.append(item);
        markField(e.loc);
      }
      box.append(list);
    }
    if (err.status === 401) {
      box.append(document.createTextNode(" Enter the server's API key at the top right."));
    }
    box.hidden = false;
  }

  function clearError() {
    $("error").hidden = true;
    document.querySelectorAll(".invalid").forEach((el) => el.classList.remove("invalid"));
  }

  function markField(loc) {
    const path = loc.filter((p) => p !== "body").join(".");
    document.querySelectorAll("[data-loc]").forEach((el) => {
      if (path === el.dataset.loc || path.startsWith(el.dataset.loc + ".")) el.classList.add("invalid");
    });
  }

  function showKeyForm() {
    $("key-form").hidden = false;
    $("api-key").focus();
  }

  // ------------------------------------------------------------------ examples and the form

  async function loadExamples() {
    const select = $("example");
    try {
      const all = await api("/v1/examples");
      const plans = all.filter((e) => e.kind === "plan");
      select.replaceChildren();
      for (const e of plans) select.append(new Option(e.title, e.name));
      select.append(new Option("(pasted scene)", ""));
      state.examples = plans;
      $("example-note").textContent = plans.length ? (plans[0].description || "")
        : "This server offers no plan example: paste a scene under Scene JSON.";
      if (plans.length) useExample(plans[0].name);
      clearError();
    } catch (err) {
      select.replaceChildren(new Option("(examples unavailable)", ""));
      showError(err, "Loading the examples");
    }
  }

  function useExample(name) {
    const e = state.examples.find((x) => x.name === name);
    if (!e) return;
    $("example").value = name;
    $("example-note").textContent = e.description || "";
    setScene(structuredClone(e.request));
  }

  function setScene(scene) {
    state.scene = scene;
    renderRobotForm();
    $("scene-json").value = JSON.stringify(scene, null, 2);
    sceneChanged();
  }

  /** After any change of the scene: without a plan, draw the edited arm at its start;
   *  with one, say that the plan shown is of an earlier scene. */
  function sceneChanged() {
    state.previewView = null;
    if (state.plan) $("stale").hidden = false;
    else drawArm();
  }

  /** Forget the plan shown (a refused edit must not sit beside the old plan). */
  function clearPlan(why) {
    if (state.playing) togglePlay();
    Object.assign(state, { plan: null, robot: null, frames: null, sigma: null, view: null, t: 0 });
    state.plots.forEach((p) => prepare(p.canvas));
    state.plots = [];
    const dt = document.createElement("dt"), dd = document.createElement("dd");
    dt.textContent = "–";
    dd.textContent = why;
    $("summary").replaceChildren(dt, dd);
    $("crossings").replaceChildren();
    $("downloads").hidden = true;
    $("stale").hidden = true;
    $("play").disabled = true;
    $("time").disabled = true;
    $("time-label").textContent = "t = –";
    $("arm-caption").textContent = START_CAPTION;
    drawArm();
  }

  const LINK_FIELDS = [["length", 0.001], ["mass", 0.01], ["inertia", 0.001]];
  const WAVE_FIELDS = [["amplitude", 0.005], ["frequency", 1], ["phase", 0.05]];

  function numberInput(value, step, loc, onChange) {
    const input = document.createElement("input");
    input.type = "number";
    input.step = String(step);
    input.value = value === undefined || value === null ? "" : String(value);
    input.dataset.loc = loc;
    input.addEventListener("input", () => onChange(input));
    return input;
  }

  function renderRobotForm() {
    const robot = state.scene && state.scene.robot;
    const body = $("links").tBodies[0];
    body.replaceChildren();
    if (!robot || !Array.isArray(robot.links)) return;
    $("gravity").value = robot.gravity ?? 0;
    $("rotational").value = robot.rotational_inertia || "cumulative";
    robot.links.forEach((link, i) => {
      const row = body.insertRow();
      row.className = link.joint === "active" ? "active" : "passive";
      row.insertCell().textContent = String(i);
      const joint = document.createElement("select");
      joint.append(new Option("passive"), new Option("active"));
      joint.value = link.joint;
      joint.dataset.loc = `robot.links.${i}.joint`;
      joint.addEventListener("change", () => {
        link.joint = joint.value;
        if (link.joint === "passive") delete link.wave;
        renderRobotForm();
        sceneEdited();
      });
      row.insertCell().append(joint);
      for (const [field, step] of LINK_FIELDS) {
        const input = numberInput(link[field], step, `robot.links.${i}.${field}`, (el) => {
          const v = parseFloat(el.value);
          const blank = field === "inertia" && el.value.trim() === "";
          el.classList.toggle("invalid", !Number.isFinite(v) && !blank);
          if (blank) delete link[field];
          else if (Number.isFinite(v)) link[field] = v;
          sceneEdited();
        });
        if (field === "inertia") input.placeholder = "0";
        row.insertCell().append(input);
      }
      for (const [field, step] of WAVE_FIELDS) {
        const wave = link.wave || {};
        const input = numberInput(wave[field], step, `robot.links.${i}.wave.${field}`,
          (el) => editWave(link, field, el));
        input.disabled = link.joint !== "active";
        input.placeholder = link.joint === "active" && field === "amplitude" ? "none" : "";
        row.insertCell().append(input);
      }
    });
  }

  function editWave(link, field, input) {
    const text = input.value.trim();
    if (field === "amplitude" && text === "") {
      link.wave = null;
      input.classList.remove("invalid");
      sceneEdited();
      return;
    }
    const v = parseFloat(text);
    input.classList.toggle("invalid", !Number.isFinite(v));
    if (!Number.isFinite(v)) return;
    link.wave = { amplitude: 0, frequency: 1, phase: 0, ...(link.wave || {}), [field]: v };
    sceneEdited();
  }

  function sceneEdited() {
    $("example").value = "";
    $("scene-json").value = JSON.stringify(state.scene, null, 2);
    sceneChanged();
  }

  function applyJson() {
    clearError();
    try {
      const scene = JSON.parse($("scene-json").value);
      if (!scene || typeof scene !== "object" || Array.isArray(scene)) throw new Error("a scene is a JSON object");
      $("example").value = "";
      setScene(scene);
    } catch (err) {
      showError(new Problem(0, { title: "The scene JSON cannot be read", detail: err.message }));
    }
  }

  // ------------------------------------------------------------------ planning

  async function startPlan() {
    clearError();
    stopPolling();
    if (!state.scene) { showError(new Problem(0, { title: "No scene", detail: "choose an example or paste a scene" })); return; }
    $("plan").disabled = true;
    showProgress({ status: "submitting", progress: null });
    state.submitted = structuredClone(state.scene);
    try {
      const job = await api("/v1/plans", { method: "POST", body: JSON.stringify(state.submitted) });
      state.job = job;
      $("cancel").hidden = false;
      onJob(job);
    } catch (err) {
      $("plan").disabled = false;
      $("progress").hidden = true;
      showError(err, "The scene was refused");
      if (state.plan) clearPlan("no plan: the edited scene was refused (see the error); the earlier plan is cleared");
    }
  }

  function stopPolling() {
    if (state.pollTimer) clearTimeout(state.pollTimer);
    state.pollTimer = null;
  }

  async function poll() {
    try {
      onJob(await api(`/v1/plans/${state.job.id}`));
    } catch (err) {
      showError(err, "Following the job");
      state.pollTimer = setTimeout(poll, 4 * POLL_MS);
    }
  }

  function onJob(job) {
    state.job = job;
    showProgress(job);
    if (!FINAL.has(job.status)) {
      state.pollTimer = setTimeout(poll, POLL_MS);
      return;
    }
    stopPolling();
    $("plan").disabled = false;
    $("cancel").hidden = true;
    if (job.status !== "succeeded" && job.error) {
      showError(new Problem(0, { title: `The job ${job.status}`, detail: job.error }));
    }
    // a task refused as infeasible before a solve has a plan without trajectory
    if (job.plan && job.plan.t.length) showPlan(job).catch((err) => showError(err, "Showing the plan"));
  }

  async function cancelPlan() {
    if (!state.job) return;
    try { onJob(await api(`/v1/plans/${state.job.id}`, { method: "DELETE" })); }
    catch (err) { showError(err, "Cancelling"); }
  }

  const fmt = (v, digits = 4) => (v === null || v === undefined || !Number.isFinite(v)) ? "–"
    : (Math.abs(v) >= 1e4 || (Math.abs(v) < 1e-3 && v !== 0)) ? v.toExponential(2) : v.toPrecision(digits);

  function showProgress(job) {
    $("progress").hidden = false;
    const p = job.progress;
    const maxIter = (state.scene.solver && state.scene.solver.max_iter) || 500;
    $("p-status").textContent = job.status + (job.cancel_requested && !FINAL.has(job.status) ? " (cancelling)" : "");
    $("p-iteration").textContent = p ? `${p.iteration} / ${maxIter}` : "–";
    $("p-objective").textContent = p ? fmt(p.objective, 6) : "–";
    $("p-infpr").textContent = p ? fmt(p.inf_pr, 3) : "–";
    $("p-elapsed").textContent = p ? `${p.elapsed.toFixed(1)} s` : "–";
    const done = FINAL.has(job.status) ? 1 : p ? Math.min(1, p.iteration / maxIter) : 0.02;
    $("progress-fill").style.width = `${(100 * done).toFixed(1)}%`;
  }

  // ------------------------------------------------------------------ the plan

  function planRobot(robot, plan) {
    const out = structuredClone(robot);
    for (const w of plan.waves || []) {
      out.links[w.joint].wave = { amplitude: w.amplitude, frequency: w.frequency, phase: w.phase };
    }
    return out;
  }

  async function showPlan(job) {
    const plan = job.plan;
    state.plan = plan;
    state.robot = planRobot(state.submitted.robot, plan);
    state.frames = plan.dense.q.map((q) => joints(state.robot, q));
    state.t = 0;
    $("stale").hidden = true;
    renderSummary(job);
    setupPlayer();
    state.sigma = sigmaOf(plan, state.robot);
    buildPlots();
    drawAll();
    if (!state.playing) togglePlay();
  }

  /** sigma_min(M_pa) at the dense samples, with and without the waves, as the plan carries it. */
  function sigmaOf(plan, robot) {
    if (!robot.links.some((l) => l.joint === "passive")) return { note: "no passive joint: no coupling block" };
    const v = plan.verification;
    if (!v.sigma_min || v.sigma_min.length !== plan.dense.t.length) return { note: "sigma_min not recorded in this plan" };
    return { with: v.sigma_min, without: v.waveless_sigma_min };
  }

  // the objective's terms: weight's field, integral, unit (planner.plots.objective_text)
  const TERMS = [["effort", "∫|τ|² dt", "N²m²s"], ["time", "T", "s"],
                 ["smoothness", "∫|dτ/dt|² dt", "N²m²/s"]];

  /** "1.12246 N²m²s (effort ∫|τ|² dt)": the value with the scene's weighted terms, and a
   *  unit when there is one term. */
  function objectiveText(value, task) {
    const weights = { effort: 1, time: 0, smoothness: 0, ...((task && task.objective) || {}) };
    const used = TERMS.map(([name, integral, unit]) => [name, integral, unit, weights[name]])
      .filter((term) => term[3] > 0);
    const tracking = task && task.tracking;
    if (tracking && tracking.mode === "weighted") {
      used.push(["tracking", "∫|q_p − q_ref|² dt", "rad²s", tracking.weight ?? 100]);
    }
    if (!used.length) return fmt(value, 6);
    const terms = used.map(([name, integral, , w]) => w === 1 ? `${name} ${integral}` : `${name} ${w}·${integral}`);
    const unit = used.length === 1 && Number.isFinite(value) ? ` ${used[0][2]}` : "";
    return `${fmt(value, 6)}${unit} (${terms.join(" + ")})`;
  }

  function renderSummary(job) {
    const { plan } = job;
    const s = plan.solver, v = plan.verification;
    const status = plan.status ?? (v.verified ? "verified" : "not verified");
    const rows = [
      ["status", status, status === "verified" ? "good" : "bad"],
      ["message", plan.message ?? s.message],
      ["last solve", `${s.status}: ${s.message}`, s.success ? "good" : "bad"],
      ["iterations", String(s.iterations)],
      ["objective", objectiveText(plan.objective, state.submitted.task)],
      ["duration T", `${fmt(plan.duration)} s`],
      ["time", `build ${s.build_time.toFixed(2)} s · solve ${s.solve_time.toFixed(2)} s`],
      ["re-simulation", v.resimulation_error === null ? v.resimulation_status : `${fmt(v.resimulation_error, 3)} rad`,
        v.verified === true ? "good" : v.verified === false ? "bad" : undefined],
      ["verified", v.verified == null ? "not recorded" : v.verified ? `yes (tolerance ${v.tolerance} rad)` : "no (the message says why)"],
      ["defect", v.defect === null ? "–" : `${fmt(v.defect, 3)} N m s`],
      ["min σ_min", fmt(v.min_sigma, 3) + " (with waves)"],
      ["waveless min", fmt(v.waveless_min_sigma, 3)],
      ["waves", (plan.waves || []).map((w) => `q${w.joint}: a ${fmt(w.amplitude, 3)}, n ${fmt(w.frequency, 3)}, ε ${fmt(w.phase, 3)}`).join("; ") || "none"],
    ];
    const dl = $("summary");
    dl.replaceChildren();
    for (const [k, val, cls] of rows) {
      const dt = document.createElement("dt"); dt.textContent = k;
      const dd = document.createElement("dd"); dd.textContent = val;
      if (cls) dd.className = cls;
      dl.append(dt, dd);
    }
    const list = $("crossings");
    list.replaceChildren();
    const crossings = v.waveless_singular_crossings || [];
    const head = document.createElement("li");
    head.textContent = crossings.length
      ? `${crossings.length} configuration(s) singular without the waves:` : "no waveless singular crossing";
    head.style.listStyle = "none";
    list.append(head);
    for (const c of crossings) {
      const li = document.createElement("li");
      li.textContent = `t = ${c.time.toFixed(3)} s, q = [${c.q.map((x) => x.toFixed(2)).join(", ")}]`;
      li.style.cursor = "pointer";
      li.addEventListener("click", () => seek(c.time));
      list.append(li);
    }
    $("downloads").hidden = false;
    for (const [id, path] of [["png", "plot.png"], ["svg", "plot.svg"], ["json", ""]]) {
      $(id).href = `/v1/plans/${job.id}${path ? "/" + path : ""}`;
    }
  }

  async function openAuthenticated(event) {
    if (!localStorage.getItem(KEY_STORE)) return; // a plain link works without a key
    event.preventDefault();
    const target = window.open("", "_blank");
    try {
      const blob = await api(event.currentTarget.getAttribute("href"), { raw: true });
      target.location = URL.createObjectURL(blob);
    } catch (err) {
      target.close();
      showError(err, "Downloading");
    }
  }

  // ------------------------------------------------------------------ kinematics

  function radius(link, q) {
    const w = link.wave;
    return link.length + (w ? w.amplitude * Math.sin(w.frequency * q + w.phase) : 0);
  }

  /** Joint positions: the base, then the tip of every link [m], model coordinates (x, y). */
  function joints(robot, q) {
    const points = [[0, 0]];
    let x = 0, y = 0;
    robot.links.forEach((link, i) => {
      const r = radius(link, q[i]);
      x += r * Math.cos(q[i]);
      y += r * Math.sin(q[i]);
      points.push([x, y]);
    });
    return points;
  }

  /** The wavy mass path r(q) e(q) of a link around its joint, for angles from a to b. */
  function wavePath(link, origin, a, b, count) {
    const out = [];
    for (let k = 0; k <= count; k++) {
      const q = a + (b - a) * k / count;
      const r = radius(link, q);
      out.push([origin[0] + r * Math.cos(q), origin[1] + r * Math.sin(q)]);
    }
    return out;
  }

  // ------------------------------------------------------------------ canvas helpers

  /** Size a canvas to its CSS width at the device pixel ratio; returns [ctx, width, height]. */
  function prepare(canvas) {
    const ratio = window.devicePixelRatio || 1;
    if (!canvas.dataset.aspect) canvas.dataset.aspect = String(canvas.height / canvas.width);
    const width = canvas.clientWidth || canvas.width;
    const height = Math.round(width * parseFloat(canvas.dataset.aspect));
    if (canvas.width !== Math.round(width * ratio)) {
      canvas.width = Math.round(width * ratio);
      canvas.height = Math.round(height * ratio);
    }
    const ctx = canvas.getContext("2d");
    ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
    ctx.clearRect(0, 0, width, height);
    return [ctx, width, height];
  }

  function sampleAt(t, times, values) {
    // linear interpolation of time-major rows at time t
    let lo = 0, hi = times.length - 1;
    if (t <= times[0]) return values[0];
    if (t >= times[hi]) return values[hi];
    while (hi - lo > 1) { const mid = (lo + hi) >> 1; if (times[mid] <= t) lo = mid; else hi = mid; }
    const u = (t - times[lo]) / (times[hi] - times[lo] || 1);
    const a = values[lo], b = values[hi];
    return a.map((v, i) => v + u * (b[i] - v));
  }

  // ------------------------------------------------------------------ the arm

  function armView() {
    const pts = [];
    const step = Math.max(1, Math.floor(state.frames.length / 150));
    for (let k = 0; k < state.frames.length; k += step) pts.push(...state.frames[k]);
    const stride = Math.max(1, Math.floor(state.frames.length / 8));
    state.robot.links.forEach((link, j) => {
      if (link.joint !== "active") return;
      for (let k = 0; k < state.frames.length; k += stride) {
        pts.push(...wavePath(link, state.frames[k][j], 0, 2 * Math.PI, 48));
      }
    });
    // screen coordinates: right = y, down = x
    const xs = pts.map((p) => p[1]), ys = pts.map((p) => p[0]);
    return { left: Math.min(...xs), right: Math.max(...xs), top: Math.min(...ys), bottom: Math.max(...ys) };
  }

  /** The scene's robot and its start q when both are readable, else null. */
  function sceneStart() {
    const robot = state.scene && state.scene.robot;
    const initial = state.scene && state.scene.task && state.scene.task.initial;
    const q = initial && initial.q;
    if (!robot || !Array.isArray(robot.links) || !robot.links.length || !Array.isArray(q)) return null;
    const numbers = (v) => Number.isFinite(v);
    if (q.length !== robot.links.length || !q.every(numbers)) return null;
    if (!robot.links.every((l) => l && numbers(l.length) && numbers(l.mass) && l.mass > 0)) return null;
    const wavy = (l) => !l.wave || ["amplitude", "frequency", "phase"].every((f) => numbers(l.wave[f]));
    return robot.links.every(wavy) ? { robot, q } : null;
  }

  function startView(robot, q) {
    const at = joints(robot, q);
    const pts = [...at];
    robot.links.forEach((link, j) => {
      if (link.joint === "active") pts.push(...wavePath(link, at[j], 0, 2 * Math.PI, 48));
    });
    const xs = pts.map((p) => p[1]), ys = pts.map((p) => p[0]);
    return { left: Math.min(...xs), right: Math.max(...xs), top: Math.min(...ys), bottom: Math.max(...ys) };
  }

  /** Without a plan: the scene's arm at its start (task.initial.q), its mass paths faint. */
  function drawStart(ctx, W, H) {
    const start = sceneStart();
    if (!start) {
      ctx.fillStyle = C.muted;
      ctx.font = "13px system-ui, sans-serif";
      ctx.fillText("no arm to draw: the scene's robot or task.initial.q is incomplete", 12, 22);
      return;
    }
    const { robot, q } = start;
    const box = state.previewView || (state.previewView = startView(robot, q));
    const S = toScreen(box, W, H);
    const now = joints(robot, q);
    robot.links.forEach((link, j) => {
      if (link.joint !== "active") return;
      ctx.strokeStyle = "rgba(255,127,14,0.30)";
      ctx.lineWidth = 1;
      polyline(ctx, wavePath(link, now[j], 0, 2 * Math.PI, 240).map(S), true);
    });
    drawLinks(ctx, robot, now, S);
    ctx.fillStyle = C.ink;
    ctx.font = "600 14px system-ui, sans-serif";
    ctx.fillText("t = 0: the scene's start (no plan yet)", 12, 22);
    gravityLabel(ctx, robot, W);
  }

  function toScreen(box, W, H) {
    const pad = 24;
    const scale = Math.min((W - 2 * pad) / Math.max(box.right - box.left, 1e-6),
                           (H - 2 * pad) / Math.max(box.bottom - box.top, 1e-6));
    const ox = W / 2 - scale * (box.left + box.right) / 2;
    const oy = H / 2 - scale * (box.top + box.bottom) / 2;
    return (p) => [ox + scale * p[1], oy + scale * p[0]];
  }

  /** Links, masses (sized by mass; orange on active joints) and the base. */
  function drawLinks(ctx, robot, now, S) {
    ctx.strokeStyle = "#2b3440";
    ctx.lineWidth = 3.5;
    ctx.lineCap = "round";
    polyline(ctx, now.map(S));
    const mmax = Math.max(...robot.links.map((l) => l.mass));
    robot.links.forEach((link, i) => {
      const [x, y] = S(now[i + 1]);
      ctx.beginPath();
      ctx.arc(x, y, 5 + 7 * Math.sqrt(link.mass / mmax), 0, 2 * Math.PI);
      ctx.fillStyle = link.joint === "active" ? C.active : C.passive;
      ctx.fill();
      ctx.strokeStyle = "#fff";
      ctx.lineWidth = 1.5;
      ctx.stroke();
    });
    const [bx, by] = S([0, 0]);
    ctx.fillStyle = "#17212d";
    ctx.fillRect(bx - 6, by - 6, 12, 12);
  }

  /** "g, x ↓" top right; without gravity only the axis ("x ↓, g = 0"). */
  function gravityLabel(ctx, robot, W) {
    ctx.font = "12px system-ui, sans-serif";
    ctx.fillStyle = C.muted;
    ctx.textAlign = "right";
    ctx.fillText(robot.gravity ? "g, x ↓" : "x ↓, g = 0", W - 12, 22);
    ctx.textAlign = "left";
  }

  function drawArm() {
    const canvas = $("arm");
    const [ctx, W, H] = prepare(canvas);
    ctx.fillStyle = "#fbfcfd";
    ctx.fillRect(0, 0, W, H);
    if (!state.plan) { drawStart(ctx, W, H); return; }
    const box = state.view || (state.view = armView());
    const S = toScreen(box, W, H);

    const plan = state.plan, t = state.t;
    const q = sampleAt(t, plan.dense.t, plan.dense.q);
    const now = joints(state.robot, q);
    const n = state.robot.links.length;

    // the last tip's path over the plan
    ctx.strokeStyle = "#cfd6de";
    ctx.lineWidth = 1;
    polyline(ctx, state.frames.map((f) => S(f[n])));

    // each active link's mass path: the whole curve faint, the part the plan sweeps solid
    state.robot.links.forEach((link, j) => {
      if (link.joint !== "active") return;
      const column = plan.dense.q.map((row) => row[j]);
      const lo = Math.min(...column), hi = Math.max(...column);
      ctx.strokeStyle = "rgba(255,127,14,0.30)";
      ctx.lineWidth = 1;
      polyline(ctx, wavePath(link, now[j], 0, 2 * Math.PI, 240).map(S), true);
      ctx.strokeStyle = C.active;
      ctx.lineWidth = 2;
      polyline(ctx, wavePath(link, now[j], lo, hi, 120).map(S));
    });

    drawLinks(ctx, state.robot, now, S);

    // labels: time, gravity, nearby waveless singular crossing
    ctx.fillStyle = C.ink;
    ctx.font = "600 14px system-ui, sans-serif";
    ctx.fillText(`t = ${t.toFixed(2)} s`, 12, 22);
    gravityLabel(ctx, state.robot, W);
    const span = plan.dense.t[plan.dense.t.length - 1] - plan.dense.t[0];
    const near = (plan.verification.waveless_singular_crossings || [])
      .find((c) => Math.abs(c.time - t) < 0.015 * span);
    if (near) {
      ctx.fillStyle = C.mark;
      ctx.font = "600 13px system-ui, sans-serif";
      ctx.fillText("singular without the waves here", 12, 42);
    }
  }

  function polyline(ctx, pts, close = false) {
    if (!pts.length) return;
    ctx.beginPath();
    ctx.moveTo(pts[0][0], pts[0][1]);
    for (let k = 1; k < pts.length; k++) ctx.lineTo(pts[k][0], pts[k][1]);
    if (close) ctx.closePath();
    ctx.stroke();
  }

  // ------------------------------------------------------------------ time plots

  function niceTicks(lo, hi, count) {
    const span = hi - lo || 1;
    const raw = span / count, mag = Math.pow(10, Math.floor(Math.log10(raw)));
    const step = [1, 2, 5, 10].map((m) => m * mag).find((s) => s >= raw) || 10 * mag;
    const out = [];
    for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9 * span; v += step) out.push(Math.abs(v) < 1e-12 * span ? 0 : v);
    return out;
  }

  /** A time plot: series [{y, color, dash, width, label}] (null y: a gap) with a legend of
   *  the labelled ones, log scale, vertical marks, a "t [s]" axis; a cursor is drawn over a cached
   *  background. */
  class TimePlot {
    constructor(canvas, t, series, options = {}) {
      Object.assign(this, { canvas, t, series, options });
      this.background = null;
      canvas.onclick = (ev) => {
        const r = canvas.getBoundingClientRect();
        const u = (ev.clientX - r.left - this.left) / (r.width - this.left - this.right);
        if (u >= 0 && u <= 1) seek(this.t[0] + u * (this.t[this.t.length - 1] - this.t[0]));
      };
    }

    render() {
      const [ctx, W, H] = prepare(this.canvas);
      const { t, series, options } = this;
      this.left = 58; this.right = 12;
      const keyed = series.filter((s) => s.label).length > 0;
      const top = keyed ? 24 : 8, bottom = 34; // the legend has its own band above the frame
      const t0 = t[0], t1 = t[t.length - 1];
      const log = !!options.log;
      const tr = (v) => log ? Math.log10(Math.max(v, SIGMA_FLOOR)) : v;
      let lo = Infinity, hi = -Infinity;
      for (const s of series) for (const v of s.y) { if (Number.isFinite(v)) { lo = Math.min(lo, tr(v)); hi = Math.max(hi, tr(v)); } }
      if (!Number.isFinite(lo)) { lo = 0; hi = 1; }
      if (log) { lo = Math.max(lo - 0.4, hi - 9); hi += 0.4; }
      else { const m = 0.06 * ((hi - lo) || 1); lo -= m; hi += m; }
      const X = (v) => this.left + (W - this.left - this.right) * (v - t0) / ((t1 - t0) || 1);
      const Y = (v) => top + (H - top - bottom) * (1 - (tr(v) - lo) / ((hi - lo) || 1));
      this.X = X;
      ctx.font = "11px system-ui, sans-serif";
      ctx.textBaseline = "middle";
      // grid and ticks
      const yticks = log ? range(Math.ceil(lo), Math.floor(hi)).map((e) => Math.pow(10, e)) : niceTicks(lo, hi, 4);
      ctx.strokeStyle = C.grid; ctx.lineWidth = 1; ctx.fillStyle = C.muted;
      for (const v of yticks) {
        const y = Y(v);
        line(ctx, this.left, y, W - this.right, y);
        ctx.textAlign = "right";
        ctx.fillText(log ? `1e${Math.round(Math.log10(v))}` : fmtTick(v), this.left - 6, y);
      }
      ctx.textAlign = "center"; ctx.textBaseline = "top";
      for (const v of niceTicks(t0, t1, 8)) {
        line(ctx, X(v), top, X(v), H - bottom);
        ctx.fillText(fmtTick(v), X(v), H - bottom + 5);
      }
      ctx.fillStyle = C.ink;
      ctx.fillText("t [s]", (this.left + W - this.right) / 2, H - bottom + 19);
      ctx.strokeStyle = "#c5ccd4";
      ctx.strokeRect(this.left, top, W - this.left - this.right, H - top - bottom);
      // marks (waveless singular crossings)
      // 1 px on a pixel centre: crisp, in exactly the mark colour
      ctx.setLineDash([5, 4]); ctx.strokeStyle = C.mark; ctx.lineWidth = 1;
      for (const m of options.marks || []) {
        const x = Math.round(X(m)) + 0.5;
        line(ctx, x, top, x, H - bottom);
      }
      ctx.setLineDash([]);
      // series
      ctx.save();
      ctx.beginPath(); ctx.rect(this.left, top, W - this.left - this.right, H - top - bottom); ctx.clip();
      for (const s of series) {
        ctx.strokeStyle = s.color; ctx.lineWidth = s.width || 1.6; ctx.setLineDash(s.dash || []);
        ctx.beginPath();
        let gap = true; // a null value (undefined there) breaks the curve
        s.y.forEach((v, k) => {
          if (!Number.isFinite(v)) { gap = true; return; }
          const x = X(t[k]), y = Y(v);
          if (gap) ctx.moveTo(x, y); else ctx.lineTo(x, y);
          gap = false;
        });
        ctx.stroke();
      }
      ctx.restore();
      ctx.setLineDash([]);
      legend(ctx, series.filter((s) => s.label), W - this.right, top / 2);
      this.canvas.setAttribute("aria-label", [...series.filter((s) => s.label).map((s) => s.label),
        "over t [s]"].join(", "));
      if (options.note) {
        ctx.fillStyle = C.muted; ctx.textAlign = "center"; ctx.textBaseline = "middle";
        ctx.fillText(options.note, W / 2, H / 2);
      }
      this.top = top; this.bottom = bottom; this.H = H;
      this.background = document.createElement("canvas");
      this.background.width = this.canvas.width;
      this.background.height = this.canvas.height;
      this.background.getContext("2d").drawImage(this.canvas, 0, 0);
    }

    cursor(time) {
      if (!this.background) this.render();
      const ctx = this.canvas.getContext("2d");
      const ratio = this.canvas.width / (this.canvas.clientWidth || this.canvas.width);
      ctx.setTransform(1, 0, 0, 1, 0, 0);
      ctx.clearRect(0, 0, this.canvas.width, this.canvas.height);
      ctx.drawImage(this.background, 0, 0);
      ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
      const x = this.X(time);
      ctx.strokeStyle = "rgba(29,39,51,0.55)"; ctx.lineWidth = 1;
      line(ctx, x, this.top, x, this.H - this.bottom);
    }
  }

  /** One line sample and label per series, right-aligned at x on the row at y. */
  function legend(ctx, series, x, y) {
    ctx.font = "11px system-ui, sans-serif"; ctx.textAlign = "left"; ctx.textBaseline = "middle";
    const widths = series.map((s) => ctx.measureText(s.label).width + 30);
    let left = x - widths.reduce((a, w) => a + w, 0);
    if (series.length) {
      ctx.fillStyle = "rgba(255, 255, 255, 0.85)";
      ctx.fillRect(left - 4, y - 8, x - left + 4, 16);
    }
    series.forEach((s, k) => {
      ctx.strokeStyle = s.color; ctx.lineWidth = s.width || 1.6; ctx.setLineDash(s.dash || []);
      line(ctx, left, y, left + 18, y);
      ctx.setLineDash([]);
      ctx.fillStyle = C.ink;
      ctx.fillText(s.label, left + 22, y);
      left += widths[k];
    });
  }

  const range = (a, b) => Array.from({ length: Math.max(0, b - a + 1) }, (_, k) => a + k);
  const fmtTick = (v) => Math.abs(v) >= 1000 || (v !== 0 && Math.abs(v) < 0.01) ? v.toExponential(0) : String(+v.toPrecision(3));

  function line(ctx, x0, y0, x1, y1) {
    ctx.beginPath(); ctx.moveTo(x0, y0); ctx.lineTo(x1, y1); ctx.stroke();
  }

  function buildPlots() {
    const plan = state.plan, robot = state.robot;
    const t = plan.dense.t;
    const marks = (plan.verification.waveless_singular_crossings || []).map((c) => c.time);
    const active = robot.links.map((l, i) => [l, i]).filter(([l]) => l.joint === "active");
    const torque = active.map(([, j], col) => ({ y: plan.dense.tau.map((row) => row[col]),
      color: COLORS[j % COLORS.length], label: `tau${j}` }));
    const angles = robot.links.map((l, j) => ({
      y: plan.dense.q.map((row) => row[j]), color: COLORS[j % COLORS.length],
      dash: l.joint === "passive" ? [6, 4] : [], label: `q${j} (${l.joint})` }));
    const sigma = state.sigma.with
      ? [{ y: state.sigma.without, color: C.without, width: 1.2, label: "without waves" },
         { y: state.sigma.with, color: C.with, width: 2, label: "with waves" }]
      : [];
    state.plots = [
      new TimePlot($("torque-plot"), t, torque, { marks }),
      new TimePlot($("sigma-plot"), t, sigma, { marks, log: true, note: state.sigma.note }),
      new TimePlot($("angle-plot"), t, angles, { marks }),
    ];
    state.plots.forEach((p) => p.render());
  }

  // ------------------------------------------------------------------ playback

  function setupPlayer() {
    state.view = null;
    $("play").disabled = false;
    $("time").disabled = false;
    $("arm-caption").textContent = "Links (grey: passive-joint mass, orange: active), each active link's mass path r(q) e(q) around its joint, wavy where it has a wave (solid: the part this plan sweeps), the last tip's path. Gravity (x) points down.";
  }

  function duration() {
    const t = state.plan.dense.t;
    return [t[0], t[t.length - 1]];
  }

  function seek(time) {
    if (!state.plan) return;
    const [t0, t1] = duration();
    state.t = Math.min(t1, Math.max(t0, time));
    drawAll();
  }

  function togglePlay() {
    state.playing = !state.playing;
    $("play").textContent = state.playing ? "❚❚" : "▶";
    state.lastTick = null;
    if (state.playing) requestAnimationFrame(tick);
  }

  function tick(now) {
    if (!state.playing || !state.plan) return;
    if (state.lastTick !== null) {
      const [t0, t1] = duration();
      state.t += (now - state.lastTick) / 1000 * parseFloat($("speed").value);
      if (state.t > t1) state.t = t0 + (state.t - t1) % ((t1 - t0) || 1);
    }
    state.lastTick = now;
    drawAll();
    requestAnimationFrame(tick);
  }

  function drawAll() {
    drawArm();
    if (!state.plan) return;
    const [t0, t1] = duration();
    $("time").value = String(Math.round(1000 * (state.t - t0) / ((t1 - t0) || 1)));
    $("time-label").textContent = `t = ${state.t.toFixed(2)} / ${t1.toFixed(2)} s`;
    state.plots.forEach((p) => p.cursor(state.t));
  }

  // ------------------------------------------------------------------ wiring

  function wire() {
    $("example").addEventListener("change", (e) => { if (e.target.value) useExample(e.target.value); });
    $("gravity").addEventListener("input", (e) => {
      const v = parseFloat(e.target.value);
      e.target.classList.toggle("invalid", !Number.isFinite(v));
      if (Number.isFinite(v) && state.scene) { state.scene.robot.gravity = v; sceneEdited(); }
    });
    $("rotational").addEventListener("change", (e) => {
      if (state.scene) { state.scene.robot.rotational_inertia = e.target.value; sceneEdited(); }
    });
    $("gravity").dataset.loc = "robot.gravity";
    $("apply-json").addEventListener("click", applyJson);
    $("plan").addEventListener("click", startPlan);
    $("cancel").addEventListener("click", cancelPlan);
    $("play").addEventListener("click", togglePlay);
    $("time").addEventListener("input", (e) => {
      if (!state.plan) return;
      const [t0, t1] = duration();
      if (state.playing) togglePlay();
      seek(t0 + (t1 - t0) * parseInt(e.target.value, 10) / 1000);
    });
    for (const id of ["png", "svg", "json"]) $(id).addEventListener("click", openAuthenticated);
    $("key-form").addEventListener("submit", (e) => {
      e.preventDefault();
      localStorage.setItem(KEY_STORE, $("api-key").value.trim());
      clearError();
      loadExamples();
    });
    window.addEventListener("resize", () => {
      state.view = null;
      if (state.plan) { state.plots.forEach((p) => p.render()); drawAll(); } else drawArm();
    });
    if (localStorage.getItem(KEY_STORE)) {
      $("api-key").value = localStorage.getItem(KEY_STORE);
    }
  }

  wire();
  drawArm();
  loadExamples();
})();
