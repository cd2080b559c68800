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
  // The size the server renders the still view at (the page's view area times the resolution
  // scale): the overlay's projection is made for it.
  const viewSize = { width: 1, height: 1 };
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
    probeMark = null;
    drawOverlay();
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
    else if (m.type === "colours") { colours = m.colours; drawColourBar(); }
    else if (m.type === "probe") showProbe(m);
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

  // ---- the view area: the server renders at its size in device pixels (times the scale) ----
  let viewportTimer = null;
  function sendViewport() {
    const v = $("view").getBoundingClientRect(), dpr = window.devicePixelRatio || 1;
    const width = Math.max(1, Math.round(v.width * dpr)), height = Math.max(1, Math.round(v.height * dpr));
    send("viewport", { type: "viewport", width, height });
  }
  // A resize is sent once it pauses: each new size empties the image.
  window.addEventListener("resize", () => {
    clearTimeout(viewportTimer);
    viewportTimer = setTimeout(sendViewport, 150);
  });
  $("scale").onchange = (e) => send("scale", { type: "scale", scale: +e.target.value });

  function stats(m) {
    if (m.view_width && (m.view_width !== viewSize.width || m.view_height !== viewSize.height)) {
      viewSize.width = m.view_width;
      viewSize.height = m.view_height;
      drawOverlay();
    }
    $("stats").textContent =
      `${m.method}, ${m.width}x${m.height}${m.moving ? " (moving)" : ""}${m.denoised ? (m.denoised_spp ? `, denoised at ${m.denoised_spp} spp` : ", denoised") : ""}\n` +
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
    const d = m.data, mb = (b) => `${(b / 1048576).toFixed(b < 10485760 ? 2 : 0)} MB`;
    $("data").textContent =
      `${d.file}\n${d.dims.join(" x ")} voxels, ${d.dtype}\n` +
      `spacing ${d.spacing.map(fmt).join(" x ")}${d.units ? " " + d.units : " (no unit given)"}\nvalues ${fmt(m.range[0])} to ${fmt(m.range[1])}\n` +
      `memory: voxels ${mb(d.voxel_bytes)}, with majorants ${mb(d.medium_bytes)}`;
    buildClip();
    restore(m);
    sendViewport();
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
    viewSize.width = m.view_width;
    viewSize.height = m.view_height;
    const scale = $("scale");
    if (![...scale.options].some((o) => +o.value === m.scale)) scale.add(new Option(`${m.scale}`, m.scale));
    scale.value = m.scale;
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
    restoreChannels(m);
    restoreTime(m);
    colours = m.colours;
    views = m.views;
    showViews();
    drawCurve();
    drawColourBar();
    drawOverlay();
  }

  // ---- channels: the scene's [[channel]] tables, each shown or hidden ----
  function restoreTime(m) {
    const n = m.time_points || 1;
    $("time-section").hidden = n <= 1;
    $("time").max = n - 1;
    $("time").value = m.time || 0;
    $("time-value").textContent = `${m.time || 0} of ${n}`;
  }
  $("time").oninput = (e) => { $("time-value").textContent = `${e.target.value} of ${+e.target.max + 1}`; };
  // Sent when the slider is let go: each time point reads the volume again.
  $("time").onchange = (e) => send("time", { type: "time", time: +e.target.value });

  function restoreChannels(m) {
    const channels = m.channels || [];
    $("channel-section").hidden = channels.length === 0;
    const box = $("channels");
    box.innerHTML = "";
    channels.forEach((c, k) => {
      const label = document.createElement("label");
      const rgb = c.color.map((v) => Math.round(255 * Math.min(1, Math.max(0, v)))).join(",");
      label.innerHTML = `<input type="checkbox" data-channel="${k}"${c.visible ? " checked" : ""}>
        <span class="swatch" style="background: rgb(${rgb})"></span> channel ${c.index}`;
      label.querySelector("input").onchange = (e) =>
        send(`channel${k}`, { type: "channel", channel: k, visible: e.target.checked });
      box.appendChild(label);
    });
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
    // The section shows itself while anything is cut away.
    if (c.box || planes.length) $("clip-section").open = true;
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

  // ---- where the image lies on the page, and the camera's projection ----
  // The image is shown whole (object-fit: contain): its rectangle inside the view, in the
  // view's CSS pixels.
  function imageRect() {
    const v = $("view").getBoundingClientRect();
    const k = Math.min(v.width / viewSize.width, v.height / viewSize.height);
    const w = viewSize.width * k, h = viewSize.height * k;
    return { left: (v.width - w) / 2, top: (v.height - h) / 2, width: w, height: h, scale: k };
  }
  // World point to the view's CSS pixels through the page's camera (the server's pinhole:
  // right = forward x up, down = forward x right, focal length from the vertical field of view);
  // null behind the camera.
  function projector() {
    const e = eye(), forward = norm(sub(state.target, e));
    const right = norm(cross(forward, state.up)), down = cross(forward, right);
    const r = imageRect();
    const focal = 0.5 * viewSize.height / Math.tan(hello.camera.fov_y * Math.PI / 360);
    return (p) => {
      const v = sub(p, e), z = dot(v, forward);
      if (z <= 1e-6) return null;
      return [r.left + (0.5 * viewSize.width + focal * dot(v, right) / z) * r.scale,
              r.top + (0.5 * viewSize.height + focal * dot(v, down) / z) * r.scale];
    };
  }

  // ---- the overlay: the volume's box, an axis triad and a scale bar; the probed point ----
  let probeMark = null;
  function drawOverlay() {
    const c = $("overlay");
    if (!hello) return;
    const v = $("view").getBoundingClientRect(), dpr = window.devicePixelRatio || 1;
    c.width = Math.round(v.width * dpr);
    c.height = Math.round(v.height * dpr);
    const g = c.getContext("2d");
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.clearRect(0, 0, v.width, v.height);
    const r = imageRect();
    if ($("guides").checked) {
      const project = projector();
      const [lo, hi] = hello.bounds;
      const corner = (i) => [i & 1 ? hi[0] : lo[0], i & 2 ? hi[1] : lo[1], i & 4 ? hi[2] : lo[2]];
      g.strokeStyle = "#9e9e9e88";
      g.lineWidth = 1;
      for (let i = 0; i < 8; i++) for (const bit of [1, 2, 4]) {
        if (i & bit) continue;
        const a = project(corner(i)), b = project(corner(i | bit));
        if (!a || !b) continue;
        g.beginPath(); g.moveTo(...a); g.lineTo(...b); g.stroke();
      }
      // The triad: the world axes as the camera turns them, in the image's lower-left corner.
      const e = eye(), forward = norm(sub(state.target, e));
      const right = norm(cross(forward, state.up)), down = cross(forward, right);
      const o = [r.left + 34, r.top + r.height - 34];
      [["x", [1, 0, 0], "#ef5350"], ["y", [0, 1, 0], "#66bb6a"], ["z", [0, 0, 1], "#42a5f5"]].forEach(([name, a, colour]) => {
        const tip = [o[0] + 24 * dot(a, right), o[1] + 24 * dot(a, down)];
        g.strokeStyle = g.fillStyle = colour;
        g.lineWidth = 2;
        g.beginPath(); g.moveTo(...o); g.lineTo(...tip); g.stroke();
        g.font = "11px system-ui";
        g.fillText(name, tip[0] + 3, tip[1] + 3);
      });
      // The scale bar: a round length (1, 2 or 5 x 10^k world units) near a fifth of the
      // image's width, at the distance of the orbit's target.
      const focal = 0.5 * viewSize.height / Math.tan(hello.camera.fov_y * Math.PI / 360);
      const perPixel = dot(sub(state.target, e), forward) / focal / r.scale;
      const want = 0.2 * r.width * perPixel, p10 = Math.pow(10, Math.floor(Math.log10(want)));
      const length = [1, 2, 5, 10].map((k) => k * p10).filter((l) => l <= want).pop() || p10;
      const px = length / perPixel, x0 = r.left + r.width - 16 - px, y0 = r.top + r.height - 16;
      g.strokeStyle = g.fillStyle = "#e0e0e0";
      g.lineWidth = 2;
      g.beginPath(); g.moveTo(x0, y0 - 4); g.lineTo(x0, y0); g.lineTo(x0 + px, y0); g.lineTo(x0 + px, y0 - 4); g.stroke();
      g.font = "11px system-ui";
      g.fillText(`${fmt(length)} ${hello.data.units || "(scene units)"}`, x0, y0 - 7);
    }
    if (probeMark) {
      const [x, y] = [r.left + probeMark[0] * r.width, r.top + probeMark[1] * r.height];
      g.strokeStyle = "#ffeb3b";
      g.lineWidth = 1.5;
      g.beginPath(); g.arc(x, y, 6, 0, 2 * Math.PI); g.moveTo(x - 10, y); g.lineTo(x + 10, y); g.moveTo(x, y - 10); g.lineTo(x, y + 10); g.stroke();
    }
  }
  window.addEventListener("resize", drawOverlay);
  $("guides").onchange = drawOverlay;

  // ---- probing: a click (no drag) on the image ----
  function probeAt(clientX, clientY) {
    const v = $("view").getBoundingClientRect(), r = imageRect();
    const x = (clientX - v.left - r.left) / r.width, y = (clientY - v.top - r.top) / r.height;
    if (!(x >= 0 && x <= 1 && y >= 0 && y <= 1)) return;
    probeMark = [x, y];
    drawOverlay();
    $("data-section").open = true;
    send("probe", { type: "probe", x, y });
  }
  function showProbe(m) {
    const h = m.hit;
    $("probe").textContent = h
      ? `at (${h.position.map(fmt).join(", ")}), ${fmt(h.distance)} from the camera\n` +
        `voxel (${h.voxel.join(", ")}): value ${fmt(h.value)}\n` +
        `filtered ${fmt(h.filtered)}, opacity ${fmt(h.opacity)}`
      : "the ray meets no visible medium";
  }

  // ---- views: along each axis, and named views kept with the scene ----
  let views = [];
  function lookAlong(axis) {
    // Looking along -axis from the +axis side, at the volume's centre, from the same distance;
    // straight along the up axis is not a frame the camera can take, so 86 degrees.
    const { up, e1, e2 } = frame();
    state.target = state.centre.slice();
    state.elevation = Math.max(-1.5, Math.min(1.5, Math.asin(Math.max(-1, Math.min(1, dot(axis, up))))));
    if (Math.abs(dot(axis, up)) < 0.999) state.azimuth = Math.atan2(dot(axis, e2), dot(axis, e1));
    sendCamera(false);
  }
  [["+x", [1, 0, 0]], ["-x", [-1, 0, 0]], ["+y", [0, 1, 0]], ["-y", [0, -1, 0]], ["+z", [0, 0, 1]], ["-z", [0, 0, -1]]].forEach(([name, axis]) => {
    const b = document.createElement("button");
    b.textContent = name;
    b.title = `view from ${name}`;
    b.onclick = () => lookAlong(axis);
    $("axis-views").appendChild(b);
  });
  function showViews() {
    const box = $("views");
    box.innerHTML = "";
    for (const v of views) {
      const row = document.createElement("div");
      const go = document.createElement("button");
      go.textContent = v.name;
      go.title = "go to this view";
      go.onclick = () => { setFromEye(v.eye, v.target); sendCamera(false); };
      const drop = document.createElement("button");
      drop.textContent = "×";
      drop.title = `forget ${v.name}`;
      drop.onclick = () => send("view", { type: "view", name: v.name, remove: true });
      row.append(go, drop);
      box.appendChild(row);
    }
  }
  $("view-keep").onclick = () => {
    const name = $("view-name").value.trim();
    if (!name) { showError("view name: expected a name", false); return; }
    send("view", { type: "view", name });
    $("view-name").value = "";
  };

  // ---- camera: orbit (left drag), pan (right or shift drag), zoom (wheel, pinch) ----
  const view = $("view");
  const pointers = new Map();
  let pinch = null;
  view.addEventListener("contextmenu", (e) => e.preventDefault());
  view.addEventListener("pointerdown", (e) => {
    view.setPointerCapture(e.pointerId);
    pointers.set(e.pointerId, { x: e.clientX, y: e.clientY, x0: e.clientX, y0: e.clientY, moved: false, pan: e.button === 2 || e.shiftKey });
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
    // A press that stays within 3 pixels is a click (a probe), not a drag.
    if (!p.moved && Math.hypot(e.clientX - p.x0, e.clientY - p.y0) <= 3) return;
    p.moved = true;
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
    const p = pointers.get(e.pointerId);
    const click = p && !p.moved && !p.pan && pointers.size === 1 && e.type === "pointerup";
    pointers.delete(e.pointerId);
    if (pointers.size < 2) pinch = null;
    if (!hello || pointers.size > 0) return;
    if (click) probeAt(e.clientX, e.clientY);
    else if (p && p.moved) sendCamera(false);
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
  // The colour bar: the transfer function's colour over its window, the window's ends below.
  let colours = [];
  function drawColourBar() {
    const c = $("colour-bar"), g = c.getContext("2d");
    g.clearRect(0, 0, c.width, c.height);
    if (!colours.length) return;
    const grad = g.createLinearGradient(0, 0, c.width, 0);
    colours.forEach((rgb, i) => grad.addColorStop(i / Math.max(colours.length - 1, 1),
      `rgb(${rgb.map((v) => Math.round(255 * Math.pow(Math.max(0, Math.min(1, v)), 1 / 2.2))).join(",")})`));
    g.fillStyle = grad;
    g.fillRect(0, 0, c.width, c.height);
    $("bar-lo").textContent = fmt(transfer.window[0]);
    $("bar-hi").textContent = fmt(transfer.window[1]);
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
