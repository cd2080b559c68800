// gscache view's page: one WebSocket to the server; frames arrive as JPEG (binary messages),
// everything else as JSON. Every edit is sent as it happens (at most one per animation frame)
// and the server answers with a new image, or an error that is shown here.
"use strict";
(() => {
  const $ = (id) => document.getElementById(id);
  const token = new URLSearchParams(location.search).get("token") || "";
  const socket = new WebSocket(`ws://${location.host}/ws?token=${encodeURIComponent(token)}`);
  socket.binaryType = "blob";
  let hello = null;
  let frameUrl = null;
  const state = { centre: [0, 0, 0], target: [0, 0, 0], distance: 1, azimuth: 0, elevation: 0, up: [0, 1, 0], home: null };
  const transfer = { colormap: "scene", window: [0, 1], density_scale: 1, opacity: [[0, 0], [1, 1]] };
  const lights = [];

  // ---- vectors ----
  const add = (a, b) => a.map((x, i) => x + b[i]);
  const sub = (a, b) => a.map((x, i) => x - b[i]);
  const mul = (a, k) => a.map((x) => x * k);
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const norm = (a) => mul(a, 1 / Math.max(Math.hypot(...a), 1e-12));
  // An orthonormal frame around the scene's up: azimuth and elevation are measured in it.
  function frame() {
    const up = norm(state.up);
    const ref = Math.abs(up[0]) < 0.9 ? [1, 0, 0] : [0, 0, 1];
    const e1 = norm(cross(up, ref));
    const e2 = cross(up, e1);
    return { up, e1, e2 };
  }
  function eye() {
    const { up, e1, e2 } = frame();
    const c = Math.cos(state.elevation);
    const dir = add(add(mul(e1, c * Math.cos(state.azimuth)), mul(e2, c * Math.sin(state.azimuth))), mul(up, Math.sin(state.elevation)));
    return add(state.target, mul(dir, state.distance));
  }
  function setFromEye(eyePos, target) {
    const { up, e1, e2 } = frame();
    const d = sub(eyePos, target);
    state.target = target;
    state.distance = Math.hypot(...d);
    const n = norm(d);
    state.elevation = Math.asin(Math.max(-1, Math.min(1, dot(n, up))));
    state.azimuth = Math.atan2(dot(n, e2), dot(n, e1));
  }

  // ---- sending, at most once per animation frame per kind ----
  const queued = new Map();
  let scheduled = false;
  function send(kind, message) {
    queued.set(kind, message);
    if (!scheduled) {
      scheduled = true;
      requestAnimationFrame(() => {
        scheduled = false;
        if (socket.readyState === WebSocket.OPEN) for (const m of queued.values()) socket.send(JSON.stringify(m));
        queued.clear();
      });
    }
  }
  function sendCamera(moving) {
    send("camera", { type: "camera", eye: eye(), target: state.target, up: state.up, moving });
  }
  function sendTransfer() {
    send("transfer", { type: "transfer", colormap: transfer.colormap, window: transfer.window, density_scale: transfer.density_scale, opacity: transfer.opacity });
  }

  // ---- messages from the server ----
  let errorTimer = null;
  function showError(text, ok) {
    const e = $("error");
    e.textContent = text;
    e.className = ok ? "ok" : "";
    clearTimeout(errorTimer);
    errorTimer = setTimeout(() => (e.textContent = ""), 8000);
  }
  socket.onopen = () => ($("status").textContent = "connected");
  socket.onclose = (e) => ($("status").textContent = `disconnected${e.reason ? ": " + e.reason : ""}`);
  socket.onmessage = (event) => {
    if (typeof event.data !== "string") {
      const url = URL.createObjectURL(event.data);
      const img = $("frame");
      img.onload = () => { if (frameUrl) URL.revokeObjectURL(frameUrl); frameUrl = url; };
      img.src = url;
      return;
    }
    const m = JSON.parse(event.data);
    if (m.type === "hello") start(m);
    else if (m.type === "stats") stats(m);
    else if (m.type === "error") showError(m.message, false);
    else if (m.type === "state") {
      // Another page's change, or the state in force after a refused edit: the camera too,
      // unless this page is dragging it.
      if (pointers.size === 0) setFromEye(m.camera.eye, m.camera.target);
      restore(m);
    }
    else if (m.type === "saved") showError("saved: " + m.files.join(", "), true);
    else if (m.type === "levels") {
      const box = $("levels");
      box.innerHTML = "";
      m.images.forEach((src, i) => { const img = new Image(); img.src = src; img.title = `level ${i + 1}`; box.appendChild(img); });
    }
  };

  // The cache's training loss (summed over its levels), the last 120 steps.
  const losses = [];
  function drawLoss() {
    const c = $("loss"), g = c.getContext("2d");
    g.clearRect(0, 0, c.width, c.height);
    if (losses.length < 2) return;
    const top = Math.max(...losses), bottom = Math.min(...losses);
    g.strokeStyle = "#80cbc4";
    g.beginPath();
    losses.forEach((l, i) => {
      const x = i / (losses.length - 1) * c.width;
      const y = c.height - 4 - (l - bottom) / Math.max(top - bottom, 1e-12) * (c.height - 8);
      i ? g.lineTo(x, y) : g.moveTo(x, y);
    });
    g.stroke();
  }

  function stats(m) {
    $("stats").textContent =
      `${m.method}, ${m.width}x${m.height}${m.moving ? " (moving)" : ""}${m.denoised ? `, denoised at ${m.denoised_spp} spp` : ""}\n` +
      `${m.spp} / ${m.target_spp} spp, ${m.fps.toFixed(1)} frames/s\n` +
      `trace ${m.trace_ms.toFixed(1)} ms, read ${m.lookup_ms.toFixed(1)} ms, train ${m.train_ms.toFixed(1)} ms\n` +
      `denoise ${m.denoise_ms.toFixed(1)} ms, encode ${m.encode_ms.toFixed(1)} ms` +
      (m.stale && m.stale.some((x) => x !== null) ? `\nstale: ${m.stale.map((x) => x === null ? "–" : (100 * x).toFixed(1) + "%").join(" / ")}` : "") +
      (m.split ? `\nsplit: left NEE ${m.split.left_spp} spp in ${m.split.left_ms.toFixed(0)} ms, right ${m.method} ${m.spp} spp in ${m.split.right_ms.toFixed(0)} ms` : "");
    $("status").textContent = `${m.spp} spp`;
    const steps = (m.loss || []).filter((l) => l !== null);
    if (steps.length) {
      losses.push(steps.reduce((a, b) => a + b, 0));
      if (losses.length > 120) losses.shift();
      drawLoss();
    }
    const train = $("train");
    train.disabled = m.training === null;
    if (m.training !== null) train.checked = m.training;
  }

  function start(m) {
    hello = m;
    state.centre = m.centre;
    state.up = m.camera.up;
    setFromEye(m.camera.eye, m.camera.target);
    state.home = { target: state.target.slice(), distance: state.distance, azimuth: state.azimuth, elevation: state.elevation };
    const method = $("method");
    method.innerHTML = "";
    for (const name of m.methods) method.add(new Option(name, name));
    const maps = $("colormap");
    maps.innerHTML = "";
    for (const name of m.colormaps) maps.add(new Option(name, name));
    $("denoise").disabled = !m.denoiser;
    buildClip();
    restore(m);
  }

  // The view's state as the server has it (the greeting, or after a refused edit): every
  // field shows the value in force, so a bad value is not sent again with the next edit.
  function restore(m) {
    Object.assign(transfer, m.transfer);
    transfer.window = m.transfer.window.slice();
    $("method").value = m.method;
    $("colormap").value = transfer.colormap;
    // Shown as typed: the server's f32 values at 6 significant digits.
    const shown = (v) => +Number(v).toPrecision(6);
    $("window-lo").value = shown(transfer.window[0]);
    $("window-hi").value = shown(transfer.window[1]);
    $("density").value = shown(transfer.density_scale);
    $("environment").value = m.environment;
    $("environment-value").textContent = m.environment;
    showMethod(m.method, !!m.split);
    $("show-lights").checked = m.show_lights;
    // The server's state, not the page's defaults: a reload or a reconnect shows what is on.
    $("denoise").checked = !!m.denoise;
    $("split").checked = !!m.split;
    lights.length = 0;
    const box = $("lights");
    box.innerHTML = "";
    m.lights.forEach((l, i) => {
      const { up, e1, e2 } = frame();
      const light = { direction: l.direction, intensity: l.intensity };
      lights.push(light);
      const az = Math.atan2(dot(l.direction, e2), dot(l.direction, e1));
      const el = Math.asin(Math.max(-1, Math.min(1, dot(l.direction, up))));
      const div = document.createElement("div");
      div.className = "light";
      div.innerHTML = `<b>light ${i + 1}</b> (${l.kind})
        <label>azimuth <input type="range" min="-180" max="180" step="1" value="${(az * 180 / Math.PI).toFixed(0)}" data-k="az"> <output data-o="az">${(az * 180 / Math.PI).toFixed(0)}°</output></label>
        <label>elevation <input type="range" min="-89" max="89" step="1" value="${(el * 180 / Math.PI).toFixed(0)}" data-k="el"> <output data-o="el">${(el * 180 / Math.PI).toFixed(0)}°</output></label>
        <label>intensity <input type="number" step="any" min="0" value="${l.intensity}" data-k="k"></label>`;
      div.addEventListener("input", (event) => {
        const get = (k) => div.querySelector(`[data-k=${k}]`);
        // An edit changes only what it names: the intensity keeps the direction as the server
        // has it (the sliders hold whole degrees, and rebuilding from them moved the light).
        if (event.target.dataset.k !== "k") {
          div.querySelector("[data-o=az]").textContent = `${get("az").value}°`;
          div.querySelector("[data-o=el]").textContent = `${get("el").value}°`;
          const a = get("az").value * Math.PI / 180, e = get("el").value * Math.PI / 180;
          const c = Math.cos(e);
          light.direction = add(add(mul(e1, c * Math.cos(a)), mul(e2, c * Math.sin(a))), mul(up, Math.sin(e)));
        }
        const k = parseFloat(get("k").value);
        if (!Number.isFinite(k)) {
          showError(`light ${i + 1} intensity: expected a number`, false);
          get("k").value = light.intensity;
          return;
        }
        light.intensity = k;
        send(`light${i}`, { type: "light", index: i, direction: light.direction, intensity: light.intensity });
      });
      box.appendChild(div);
    });
    restoreClip(m);
    drawCurve();
  }

  // ---- clipping: a box per axis as fractions of the volume's box, and one plane ----
  // The plane's normal is given by azimuth and elevation in the scene's up frame (as the
  // lights'), its position by an offset from the volume's centre along the normal, in half
  // diagonals. Planes the scene file has beyond the first are kept as they are.
  const clip = { box: [[0, 0, 0], [1, 1, 1]], plane: false, az: 0, el: 0, offset: 0, extra: [] };
  const axisNames = ["x", "y", "z"];
  const fmt = (v) => +Number(v).toPrecision(4);
  function clipGeometry() {
    const [lo, hi] = hello.bounds;
    const centre = mul(add(lo, hi), 0.5);
    return { lo, hi, centre, half: 0.5 * Math.hypot(...sub(hi, lo)) };
  }
  function clipNormal() {
    const { up, e1, e2 } = frame();
    const a = clip.az * Math.PI / 180, e = clip.el * Math.PI / 180, c = Math.cos(e);
    return add(add(mul(e1, c * Math.cos(a)), mul(e2, c * Math.sin(a))), mul(up, Math.sin(e)));
  }
  function clipMessage() {
    const { lo, hi, centre, half } = clipGeometry();
    const whole = clip.box[0].every((f) => f <= 0) && clip.box[1].every((f) => f >= 1);
    const corner = (f) => lo.map((l, a) => l + f[a] * (hi[a] - l));
    const planes = clip.plane ? [{ point: add(centre, mul(clipNormal(), clip.offset * half)), normal: clipNormal() }] : [];
    return { type: "clip", box: whole ? null : { min: corner(clip.box[0]), max: corner(clip.box[1]) }, plane: planes.concat(clip.extra) };
  }
  function showClip() {
    const { lo, hi } = clipGeometry();
    axisNames.forEach((name, a) => {
      for (const side of [0, 1]) {
        const input = document.querySelector(`[data-clip="${name}${side}"]`);
        input.value = clip.box[side][a];
        document.querySelector(`[data-clip-out="${name}${side}"]`).textContent = fmt(lo[a] + clip.box[side][a] * (hi[a] - lo[a]));
      }
    });
    $("clip-plane").checked = clip.plane;
    $("clip-plane-controls").hidden = !clip.plane;
    for (const [id, v, unit] of [["clip-az", clip.az, "°"], ["clip-el", clip.el, "°"], ["clip-offset", clip.offset, ""]]) {
      $(id).value = v;
      $(`${id}-value`).textContent = `${fmt(v)}${unit}`;
    }
  }
  function buildClip() {
    const box = $("clip-box");
    box.innerHTML = "";
    axisNames.forEach((name, a) => {
      const row = document.createElement("div");
      row.className = "clip-axis";
      row.innerHTML = `<b>${name}</b>
        <label>from <input type="range" min="0" max="1" step="0.01" data-clip="${name}0"> <output data-clip-out="${name}0"></output></label>
        <label>to <input type="range" min="0" max="1" step="0.01" data-clip="${name}1"> <output data-clip-out="${name}1"></output></label>`;
      row.addEventListener("input", (event) => {
        const side = +event.target.dataset.clip.slice(1);
        const v = parseFloat(event.target.value);
        // The box keeps at least a hundredth of the volume on every axis.
        if (side === 0) clip.box[0][a] = Math.min(v, clip.box[1][a] - 0.01);
        else clip.box[1][a] = Math.max(v, clip.box[0][a] + 0.01);
        showClip();
        send("clip", clipMessage());
      });
      box.appendChild(row);
    });
  }
  // The clipping in force, from the server's state.
  function restoreClip(m) {
    const { lo, hi, centre, half } = clipGeometry();
    const c = m.clip || {};
    clip.box = c.box
      ? [0, 1].map((side) => lo.map((l, a) => Math.max(0, Math.min(1, ((side ? c.box.max : c.box.min)[a] - l) / (hi[a] - l)))))
      : [[0, 0, 0], [1, 1, 1]];
    const planes = c.plane || [];
    clip.plane = planes.length > 0;
    clip.extra = planes.slice(1);
    if (clip.plane) {
      const { up, e1, e2 } = frame();
      const n = norm(planes[0].normal);
      clip.az = Math.round(Math.atan2(dot(n, e2), dot(n, e1)) * 180 / Math.PI);
      clip.el = Math.round(Math.asin(Math.max(-1, Math.min(1, dot(n, up)))) * 180 / Math.PI);
      clip.offset = Math.max(-1, Math.min(1, dot(sub(planes[0].point, centre), n) / half));
    }
    showClip();
  }
  $("clip-plane").onchange = (e) => { clip.plane = e.target.checked; showClip(); send("clip", clipMessage()); };
  for (const [id, key] of [["clip-az", "az"], ["clip-el", "el"], ["clip-offset", "offset"]]) {
    $(id).oninput = (e) => { clip[key] = parseFloat(e.target.value); showClip(); send("clip", clipMessage()); };
  }
  $("clip-none").onclick = () => {
    Object.assign(clip, { box: [[0, 0, 0], [1, 1, 1]], plane: false, extra: [] });
    showClip();
    send("clip", clipMessage());
  };

  // ---- camera: orbit (left drag), pan (right or shift drag), zoom (wheel, pinch) ----
  const view = $("view");
  const pointers = new Map();
  let pinch = null;
  view.addEventListener("contextmenu", (e) => e.preventDefault());
  view.addEventListener("pointerdown", (e) => {
    view.setPointerCapture(e.pointerId);
    pointers.set(e.pointerId, { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey });
    if (pointers.size === 2) {
      const [a, b] = [...pointers.values()];
      pinch = Math.hypot(a.x - b.x, a.y - b.y);
    }
  });
  view.addEventListener("pointermove", (e) => {
    const p = pointers.get(e.pointerId);
    if (!p || !hello) return;
    const dx = e.clientX - p.x, dy = e.clientY - p.y;
    p.x = e.clientX; p.y = e.clientY;
    if (pointers.size === 2) {
      const [a, b] = [...pointers.values()];
      const d = Math.hypot(a.x - b.x, a.y - b.y);
      if (pinch) state.distance *= pinch / Math.max(d, 1);
      pinch = d;
    } else if (p.pan) {
      const forward = norm(sub(state.target, eye()));
      const right = norm(cross(forward, state.up));
      const up = cross(right, forward);
      const k = state.distance * 0.0015;
      state.target = add(state.target, add(mul(right, -dx * k), mul(up, dy * k)));
    } else {
      state.azimuth -= dx * 0.008;
      state.elevation = Math.max(-1.5, Math.min(1.5, state.elevation + dy * 0.008));
    }
    sendCamera(true);
  });
  const release = (e) => {
    pointers.delete(e.pointerId);
    if (pointers.size < 2) pinch = null;
    if (pointers.size === 0 && hello) sendCamera(false);
  };
  view.addEventListener("pointerup", release);
  view.addEventListener("pointercancel", release);
  let wheelTimer = null;
  view.addEventListener("wheel", (e) => {
    e.preventDefault();
    state.distance *= Math.exp(e.deltaY * 0.001);
    sendCamera(true);
    clearTimeout(wheelTimer);
    wheelTimer = setTimeout(() => sendCamera(false), 200);
  }, { passive: false });
  $("reset").onclick = () => {
    if (!state.home) return;
    Object.assign(state, { target: state.home.target.slice(), distance: state.home.distance, azimuth: state.home.azimuth, elevation: state.home.elevation });
    sendCamera(false);
  };

  // ---- method, denoise, save ----
  // Controls that do not apply are hidden (the cache's with NEE), and the split view's halves
  // are labelled.
  function showMethod(method, split) {
    $("cache-section").hidden = method === "nee";
    $("split-labels").hidden = !split;
    $("split-right").textContent = method;
  }
  $("method").onchange = (e) => {
    showMethod(e.target.value, $("split").checked);
    send("method", { type: "method", method: e.target.value });
  };
  $("denoise").onchange = (e) => send("denoise", { type: "denoise", on: e.target.checked });
  $("split").onchange = (e) => {
    showMethod($("method").value, e.target.checked);
    send("split", { type: "split", on: e.target.checked });
  };
  $("show-lights").onchange = (e) => send("show_lights", { type: "show_lights", on: e.target.checked });
  $("save").onclick = () => send("save", { type: "save" });
  $("train").onchange = (e) => send("train", { type: "train", on: e.target.checked });
  $("reset-cache").onclick = () => { losses.length = 0; drawLoss(); send("reset", { type: "reset_cache" }); };
  $("show-levels").onclick = () => send("levels", { type: "levels" });
  $("environment").oninput = (e) => {
    $("environment-value").textContent = e.target.value;
    send("environment", { type: "environment", intensity: parseFloat(e.target.value) });
  };

  // ---- transfer function ----
  $("colormap").onchange = (e) => { transfer.colormap = e.target.value; sendTransfer(); };
  // A field that is not a number is named and set back, not sent (it was sent as null, and
  // the server's answer named no field).
  const number = (id, label, get, apply) => ($(id).onchange = (e) => {
    const v = parseFloat(e.target.value);
    if (!Number.isFinite(v)) {
      showError(`${label}: expected a number${e.target.value ? ` ("${e.target.value}")` : ""}`, false);
      e.target.value = +Number(get()).toPrecision(6);
      return;
    }
    apply(v);
    sendTransfer();
  });
  number("window-lo", "window low", () => transfer.window[0], (v) => (transfer.window = [v, transfer.window[1]]));
  number("window-hi", "window high", () => transfer.window[1], (v) => (transfer.window = [transfer.window[0], v]));
  number("density", "density scale", () => transfer.density_scale, (v) => (transfer.density_scale = v));

  // The opacity curve over the value histogram (log counts), x: position in the window.
  const curve = $("curve");
  const ctx = curve.getContext("2d");
  function drawCurve() {
    const w = curve.width, h = curve.height;
    ctx.clearRect(0, 0, w, h);
    if (hello) {
      // The histogram is over the data range; the curve over the window.
      const [r0, r1] = hello.range, [w0, w1] = transfer.window;
      const bins = hello.histogram, top = Math.log1p(Math.max(...bins));
      ctx.fillStyle = "#3a4a5a";
      bins.forEach((c, i) => {
        const v0 = r0 + (r1 - r0) * i / bins.length, v1 = r0 + (r1 - r0) * (i + 1) / bins.length;
        const x0 = (v0 - w0) / (w1 - w0) * w, x1 = (v1 - w0) / (w1 - w0) * w;
        const bh = Math.log1p(c) / top * h;
        ctx.fillRect(x0, h - bh, Math.max(x1 - x0, 1), bh);
      });
    }
    ctx.strokeStyle = "#ffcc80";
    ctx.fillStyle = "#ffcc80";
    ctx.beginPath();
    transfer.opacity.forEach(([u, o], i) => (i ? ctx.lineTo(u * w, (1 - o) * h) : ctx.moveTo(u * w, (1 - o) * h)));
    ctx.stroke();
    for (const [u, o] of transfer.opacity) ctx.fillRect(u * w - 3, (1 - o) * h - 3, 6, 6);
  }
  let dragging = -1;
  const at = (e) => {
    const r = curve.getBoundingClientRect();
    return [Math.max(0, Math.min(1, (e.clientX - r.left) / r.width)), Math.max(0, Math.min(1, 1 - (e.clientY - r.top) / r.height))];
  };
  const nearest = ([u, o]) => {
    let best = -1, d = 0.04;
    transfer.opacity.forEach(([pu, po], i) => { const dd = Math.hypot(pu - u, (po - o) * 0.5); if (dd < d) { d = dd; best = i; } });
    return best;
  };
  curve.addEventListener("pointerdown", (e) => {
    const p = at(e);
    dragging = nearest(p);
    if (dragging < 0) {
      transfer.opacity.push(p);
      transfer.opacity.sort((a, b) => a[0] - b[0]);
      dragging = transfer.opacity.findIndex((q) => q === p);
    }
    curve.setPointerCapture(e.pointerId);
    drawCurve(); sendTransfer();
  });
  curve.addEventListener("pointermove", (e) => {
    if (dragging < 0) return;
    const [u, o] = at(e);
    const pts = transfer.opacity;
    const lo = dragging > 0 ? pts[dragging - 1][0] + 1e-3 : 0;
    const hi = dragging < pts.length - 1 ? pts[dragging + 1][0] - 1e-3 : 1;
    pts[dragging] = [Math.max(lo, Math.min(hi, u)), o];
    drawCurve(); sendTransfer();
  });
  curve.addEventListener("pointerup", () => (dragging = -1));
  curve.addEventListener("dblclick", (e) => {
    const i = nearest(at(e));
    if (i >= 0 && transfer.opacity.length > 2) { transfer.opacity.splice(i, 1); drawCurve(); sendTransfer(); }
  });
})();
