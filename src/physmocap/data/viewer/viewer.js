// physmocap viewer: a canvas-2D perspective renderer of one run (see physmocap/viz/viewer.py for the data).
// World axes: x forward, y left, z up, metres; the floor is z = 0.
"use strict";
(function () {
  const data = JSON.parse(document.getElementById("physmocap-data").textContent);
  const started = performance.now();

  function decode(base64, ArrayType) {
    const text = atob(base64);
    const bytes = new Uint8Array(text.length);
    for (let i = 0; i < text.length; i++) bytes[i] = text.charCodeAt(i);
    return new ArrayType(bytes.buffer);
  }

  const T = data.frames, P = data.names.length, fps = data.fps;
  const finalPoints = decode(data.final, Float32Array);  // (T, P, 3)
  const kinematicPoints = decode(data.kinematic, Float32Array);
  const contacts = decode(data.contacts, Uint8Array);  // (T, 4)
  const grf = decode(data.grf, Float32Array);  // (T, 4, 3) newtons
  const com = decode(data.com, Float32Array);  // (T, 3)
  const comOverSupport = decode(data.comOverSupport, Uint8Array);  // (T,)
  const support = decode(data.support, Float32Array);  // (T, 4, 2)
  const supportCounts = decode(data.supportCounts, Uint8Array);  // (T,)
  const valid = decode(data.valid, Uint8Array);  // (T,)
  const decodeMs = performance.now() - started;

  const COLOURS = { left: "#1e88e5", right: "#fb8c00", centre: "#455a64", ghost: "rgba(120,120,120,0.45)",
                    force: "#d81b60", contact: "#43a047", support: "rgba(67,160,71,0.22)", com: "#6a1b9a",
                    outside: "#e53935", grid: "#dde1e6", axis: "#b0bec5", background: "#ffffff" };
  const side = (name) => name.startsWith("left_") ? "left" : name.startsWith("right_") ? "right" : "centre";
  const edgeColour = data.edges.map(([a, b]) => {
    const sides = [side(data.names[a]), side(data.names[b])].filter((s) => s !== "centre");
    return COLOURS[sides.length ? sides[0] : "centre"];
  });
  const pelvis = Math.max(0, data.names.indexOf("pelvis"));

  const canvas = document.getElementById("scene");
  const context = canvas.getContext("2d");
  const slider = document.getElementById("time");
  const playButton = document.getElementById("play");
  const clock = document.getElementById("clock");
  const status = document.getElementById("status");
  const invalidNote = document.getElementById("invalid");
  const ghostMode = document.getElementById("ghost");
  const showForces = document.getElementById("forces");
  const showBalance = document.getElementById("balance");
  const follow = document.getElementById("follow");
  const video = document.getElementById("video");
  const videoNote = document.getElementById("video-note");
  slider.max = String(T - 1);

  // ---- the floor grid covers the whole clip ----------------------------------------------------------------
  let low = [Infinity, Infinity], high = [-Infinity, -Infinity], pelvisMean = [0, 0, 0];
  for (let t = 0; t < T; t++) {
    for (let p = 0; p < P; p++) {
      const i = (t * P + p) * 3;
      for (let k = 0; k < 2; k++) {
        low[k] = Math.min(low[k], finalPoints[i + k]);
        high[k] = Math.max(high[k], finalPoints[i + k]);
      }
    }
    for (let k = 0; k < 3; k++) pelvisMean[k] += finalPoints[(t * P + pelvis) * 3 + k] / T;
  }
  const gridStep = Math.max(high[0] - low[0], high[1] - low[1]) > 20 ? 1.0 : 0.5;
  const gridLow = low.map((v) => Math.floor((v - 1.5) / gridStep) * gridStep);
  const gridHigh = high.map((v) => Math.ceil((v + 1.5) / gridStep) * gridStep);

  // ---- orbit camera, starting at the video camera's position -------------------------------------------------
  const view = { target: [0, 0, 0], yaw: 0, pitch: 0, distance: 4, fov: 50 * Math.PI / 180 };
  function resetView() {
    view.target = [pelvisMean[0], pelvisMean[1], Math.max(0.5, pelvisMean[2])];
    const offset = data.cameraCentre.map((c, k) => c - view.target[k]);
    view.distance = Math.min(30, Math.max(1.5, Math.hypot(...offset)));
    view.yaw = Math.atan2(offset[1], offset[0]);
    view.pitch = Math.min(1.45, Math.max(-0.05, Math.asin(offset[2] / Math.max(Math.hypot(...offset), 1e-9))));
  }
  resetView();

  let eye = [0, 0, 0], right = [0, 0, 0], up = [0, 0, 0], forward = [0, 0, 0], focal = 1, centreX = 0, centreY = 0;
  const NEAR = 0.05;
  function setupView(frame) {
    const target = view.target.slice();
    if (follow.checked) {
      target[0] = finalPoints[(frame * P + pelvis) * 3];
      target[1] = finalPoints[(frame * P + pelvis) * 3 + 1];
    }
    const cp = Math.cos(view.pitch), sp = Math.sin(view.pitch);
    eye = [target[0] + view.distance * cp * Math.cos(view.yaw), target[1] + view.distance * cp * Math.sin(view.yaw),
           target[2] + view.distance * sp];
    forward = normalise(target.map((v, k) => v - eye[k]));
    right = normalise(cross(forward, [0, 0, 1]));
    up = cross(right, forward);
    focal = canvas.height / (2 * Math.tan(view.fov / 2));
    centreX = canvas.width / 2;
    centreY = canvas.height / 2;
  }
  function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
  function normalise(v) { const n = Math.hypot(...v) || 1; return v.map((x) => x / n); }
  function toView(x, y, z) {
    const d = [x - eye[0], y - eye[1], z - eye[2]];
    return [d[0] * right[0] + d[1] * right[1] + d[2] * right[2], d[0] * up[0] + d[1] * up[1] + d[2] * up[2],
            d[0] * forward[0] + d[1] * forward[1] + d[2] * forward[2]];
  }
  function toScreen(v) { return [centreX + focal * v[0] / v[2], centreY - focal * v[1] / v[2]]; }
  function screenOf(x, y, z) { const v = toView(x, y, z); return v[2] > NEAR ? toScreen(v) : null; }

  // A world segment clipped at the near plane, as screen points, or null when wholly behind the viewer.
  function segment(a, b) {
    let va = toView(a[0], a[1], a[2]), vb = toView(b[0], b[1], b[2]);
    if (va[2] <= NEAR && vb[2] <= NEAR) return null;
    if (va[2] <= NEAR || vb[2] <= NEAR) {
      const s = (NEAR - va[2]) / (vb[2] - va[2]);
      const cut = va.map((v, k) => v + s * (vb[k] - v));
      if (va[2] <= NEAR) va = cut; else vb = cut;
    }
    return [toScreen(va), toScreen(vb)];
  }
  function line(a, b, colour, width) {
    const s = segment(a, b);
    if (!s) return null;
    context.strokeStyle = colour;
    context.lineWidth = width;
    context.beginPath();
    context.moveTo(s[0][0], s[0][1]);
    context.lineTo(s[1][0], s[1][1]);
    context.stroke();
    return s;
  }
  function dot(position, radius, colour, filled) {
    const s = screenOf(position[0], position[1], position[2]);
    if (!s) return;
    context.beginPath();
    context.arc(s[0], s[1], radius, 0, 2 * Math.PI);
    if (filled) { context.fillStyle = colour; context.fill(); }
    context.strokeStyle = colour;
    context.lineWidth = Math.max(1, radius / 3);
    context.stroke();
  }
  const point = (points, frame, p, offset) => [points[(frame * P + p) * 3] + offset[0],
                                               points[(frame * P + p) * 3 + 1] + offset[1],
                                               points[(frame * P + p) * 3 + 2] + offset[2]];

  // ---- scene layers -----------------------------------------------------------------------------------------
  const pixel = () => window.devicePixelRatio || 1;
  function drawGrid() {
    for (let x = gridLow[0]; x <= gridHigh[0] + 1e-9; x += gridStep) {
      line([x, gridLow[1], 0], [x, gridHigh[1], 0], Math.abs(x) < 1e-9 ? COLOURS.axis : COLOURS.grid, pixel());
    }
    for (let y = gridLow[1]; y <= gridHigh[1] + 1e-9; y += gridStep) {
      line([gridLow[0], y, 0], [gridHigh[0], y, 0], Math.abs(y) < 1e-9 ? COLOURS.axis : COLOURS.grid, pixel());
    }
  }
  function drawSupport(frame) {
    const count = supportCounts[frame];
    if (!count) return;
    const corners = [];
    for (let k = 0; k < count; k++) {
      const s = screenOf(support[(frame * 4 + k) * 2], support[(frame * 4 + k) * 2 + 1], 0);
      if (!s) return;
      corners.push(s);
    }
    context.beginPath();
    context.moveTo(corners[0][0], corners[0][1]);
    for (const c of corners.slice(1)) context.lineTo(c[0], c[1]);
    context.closePath();
    context.fillStyle = COLOURS.support;
    context.fill();
    context.strokeStyle = COLOURS.contact;
    context.lineWidth = 2 * pixel();
    context.stroke();
  }
  function drawSkeleton(points, frame, offset, ghost) {
    const width = (ghost ? 2.5 : 4) * pixel();
    data.edges.forEach(([a, b], e) => {
      line(point(points, frame, a, offset), point(points, frame, b, offset), ghost ? COLOURS.ghost : edgeColour[e],
           width);
    });
    if (!ghost) {
      for (let p = 0; p < P; p++) dot(point(points, frame, p, offset), 2.5 * pixel(), COLOURS[side(data.names[p])], true);
    }
  }
  function drawContacts(frame) {
    data.contactIds.forEach((p, k) => {
      dot(point(finalPoints, frame, p, [0, 0, 0]), 5 * pixel(), COLOURS.contact, contacts[frame * 4 + k] === 1);
    });
  }
  function drawForces(frame) {
    data.contactIds.forEach((p, k) => {
      const f = [0, 1, 2].map((c) => grf[(frame * 4 + k) * 3 + c]);
      if (Math.hypot(...f) < 1) return;
      const start = point(finalPoints, frame, p, [0, 0, 0]);
      const end = start.map((v, c) => v + f[c] * data.metresPerNewton);
      const s = line(start, end, COLOURS.force, 3 * pixel());
      if (!s) return;
      const angle = Math.atan2(s[1][1] - s[0][1], s[1][0] - s[0][0]), head = 10 * pixel();
      context.fillStyle = COLOURS.force;
      context.beginPath();
      context.moveTo(s[1][0], s[1][1]);
      context.lineTo(s[1][0] - head * Math.cos(angle - 0.4), s[1][1] - head * Math.sin(angle - 0.4));
      context.lineTo(s[1][0] - head * Math.cos(angle + 0.4), s[1][1] - head * Math.sin(angle + 0.4));
      context.closePath();
      context.fill();
    });
  }
  function drawCentreOfMass(frame) {
    const c = [com[frame * 3], com[frame * 3 + 1], com[frame * 3 + 2]];
    const ground = [c[0], c[1], 0];
    const colour = supportCounts[frame] === 0 ? COLOURS.axis : comOverSupport[frame] ? COLOURS.contact : COLOURS.outside;
    context.setLineDash([6 * pixel(), 4 * pixel()]);
    line(c, ground, COLOURS.com, 1.5 * pixel());
    context.setLineDash([]);
    const r = 0.06;
    line([c[0] - r, c[1], 0], [c[0] + r, c[1], 0], colour, 3 * pixel());
    line([c[0], c[1] - r, 0], [c[0], c[1] + r, 0], colour, 3 * pixel());
    dot(c, 6 * pixel(), COLOURS.com, true);
  }

  // ---- drawing a frame ---------------------------------------------------------------------------------------
  let frame = 0, drawCount = 0, lastDrawMs = 0, needsDraw = true;
  function resize() {
    const width = Math.max(1, Math.round(canvas.clientWidth * pixel()));
    const height = Math.max(1, Math.round(canvas.clientHeight * pixel()));
    if (canvas.width !== width || canvas.height !== height) { canvas.width = width; canvas.height = height; }
  }
  function draw() {
    const begin = performance.now();
    resize();
    setupView(frame);
    context.fillStyle = COLOURS.background;
    context.fillRect(0, 0, canvas.width, canvas.height);
    context.lineCap = "round";
    drawGrid();
    if (showBalance.checked) drawSupport(frame);
    if (ghostMode.value !== "hidden") {
      drawSkeleton(kinematicPoints, frame, ghostMode.value === "beside" ? data.ghostOffset : [0, 0, 0], true);
    }
    drawSkeleton(finalPoints, frame, [0, 0, 0], false);
    drawContacts(frame);
    if (showForces.checked && data.hasForces) drawForces(frame);
    if (showBalance.checked) drawCentreOfMass(frame);
    let net = 0;
    for (let c = 0; c < 3; c++) {
      let sum = 0;
      for (let k = 0; k < 4; k++) sum += grf[(frame * 4 + k) * 3 + c];
      net += sum * sum;
    }
    const seconds = frame / fps;
    clock.textContent = `${seconds.toFixed(2)} s`;
    status.textContent = `frame ${frame + 1} / ${T}` +
      (data.hasForces ? ` · ground reaction force ${(100 * Math.sqrt(net) / data.bodyWeight).toFixed(0)}% of body weight` : "");
    invalidNote.style.display = valid[frame] ? "none" : "block";
    slider.value = String(frame);
    drawCount += 1;
    lastDrawMs = performance.now() - begin;
    needsDraw = false;
  }

  // ---- playback: the video is the clock when it plays, else the page's own clock -----------------------------
  let playing = false, videoUsable = false, clockOrigin = 0, frameAtOrigin = 0;
  function restartClock() { clockOrigin = performance.now(); frameAtOrigin = frame; }
  function setFrame(value, seekVideo = true) {
    frame = Math.min(T - 1, Math.max(0, Math.round(value)));
    if (seekVideo && videoUsable) video.currentTime = (frame + 0.5) / fps;
    restartClock();
    needsDraw = true;
  }
  function play() {
    if (frame >= T - 1) setFrame(0);
    playing = true;
    playButton.textContent = "❚❚ pause";
    restartClock();
    if (videoUsable) video.play().catch(() => { videoUsable = false; restartClock(); });
  }
  function pause() {
    playing = false;
    playButton.textContent = "▶ play";
    if (videoUsable) video.pause();
  }
  function tick(now) {
    if (playing) {
      let next = videoUsable && !video.paused && !video.seeking
        ? Math.floor(video.currentTime * fps + 1e-3)
        : frameAtOrigin + Math.floor((now - clockOrigin) * fps / 1000);
      if (next >= T - 1) { next = T - 1; pause(); }
      if (next !== frame) { frame = next; needsDraw = true; }
    }
    if (needsDraw) draw();
    requestAnimationFrame(tick);
  }

  if (data.video) {
    video.addEventListener("loadeddata", () => { videoUsable = true; video.currentTime = (frame + 0.5) / fps; });
    video.addEventListener("error", () => {
      videoUsable = false;
      video.style.display = "none";
      videoNote.style.display = "block";
      videoNote.textContent = `The video ${data.video} could not be played; the 3D view plays on its own clock.`;
      if (playing) restartClock();
    });
    video.addEventListener("ended", pause);
    video.src = data.video;
  } else {
    document.getElementById("video-panel").style.display = "none";
  }

  playButton.addEventListener("click", () => (playing ? pause() : play()));
  slider.addEventListener("input", () => setFrame(Number(slider.value)));
  for (const control of [ghostMode, showForces, showBalance, follow]) {
    control.addEventListener("change", () => { needsDraw = true; });
  }
  window.addEventListener("resize", () => { needsDraw = true; });
  window.addEventListener("keydown", (event) => {
    if (event.target instanceof HTMLInputElement || event.target instanceof HTMLSelectElement) return;
    if (event.key === " ") { event.preventDefault(); playing ? pause() : play(); }
    if (event.key === "ArrowRight") setFrame(frame + 1);
    if (event.key === "ArrowLeft") setFrame(frame - 1);
  });

  let drag = null;
  canvas.addEventListener("pointerdown", (event) => {
    drag = { x: event.clientX, y: event.clientY, pan: event.shiftKey || event.button !== 0 };
    canvas.setPointerCapture(event.pointerId);
  });
  canvas.addEventListener("pointermove", (event) => {
    if (!drag) return;
    const dx = event.clientX - drag.x, dy = event.clientY - drag.y;
    drag.x = event.clientX;
    drag.y = event.clientY;
    if (drag.pan) {
      const scale = view.distance / canvas.clientHeight;
      for (let k = 0; k < 3; k++) view.target[k] += (-dx * right[k] + dy * up[k]) * scale;
    } else {
      view.yaw -= dx * 0.006;
      view.pitch = Math.min(1.5, Math.max(-0.1, view.pitch + dy * 0.006));
    }
    needsDraw = true;
  });
  canvas.addEventListener("pointerup", () => { drag = null; });
  canvas.addEventListener("contextmenu", (event) => event.preventDefault());
  canvas.addEventListener("wheel", (event) => {
    event.preventDefault();
    view.distance = Math.min(100, Math.max(0.5, view.distance * Math.exp(event.deltaY * 0.001)));
    needsDraw = true;
  }, { passive: false });
  canvas.addEventListener("dblclick", () => { resetView(); needsDraw = true; });

  draw();
  requestAnimationFrame(tick);

  // For tests and measurements: the state of the page and the screen position (CSS pixels) of a point.
  window.physmocapViewer = {
    frames: T,
    fps,
    decodeMs,
    readyAt: performance.now(),
    get frame() { return frame; },
    get playing() { return playing; },
    get videoUsable() { return videoUsable; },
    get drawCount() { return drawCount; },
    get lastDrawMs() { return lastDrawMs; },
    setFrame(value) { setFrame(value); draw(); },
    play,
    pause,
    draw,
    screenPoint(name) {
      const p = data.names.indexOf(name);
      setupView(frame);
      const s = screenOf(...point(finalPoints, frame, p, [0, 0, 0]));
      return s && [s[0] / pixel(), s[1] / pixel()];
    },
  };
})();
