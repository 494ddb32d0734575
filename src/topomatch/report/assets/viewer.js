/* topomatch correspondence viewer: a small self-contained WebGL program.
 *
 * Reads the JSON in <script id="topomatch-data">: groups of shapes (vertices, faces)
 * and, per method and pair, the stored map p2p_21 (one source vertex per target vertex)
 * and the stored per-vertex errors. Arrays are zlib-compressed little-endian buffers in
 * base64, decompressed with the browser's DecompressionStream. Left viewport: the source
 * (shape 1); right: the target (shape 2). Both share one camera.
 *
 * Test hook: window.topomatchViewer (ready, error, state, select(), pick(), project()).
 */
(function () {
  "use strict";

  const api = { ready: false, error: null, draws: 0, state: {} };
  window.topomatchViewer = api;

  const $ = (id) => document.getElementById(id);
  const status = $("viewer-status");
  function fail(msg, err) {
    api.error = msg;
    status.textContent = msg;
    status.style.display = "block";
    console.error("topomatch viewer: " + msg, err || "");
  }

  let DATA;
  try {
    DATA = JSON.parse($("topomatch-data").textContent);
  } catch (err) {
    fail("cannot read the embedded data", err);
    return;
  }
  const UNIT = DATA.error_unit;

  // ---------------------------------------------------------------- data decoding
  const TYPES = { f4: Float32Array, u2: Uint16Array, u4: Uint32Array, i4: Int32Array };
  async function decode(blob) {
    if (blob._arr) return blob._arr;
    if (typeof DecompressionStream === "undefined") {
      throw new Error("this browser has no DecompressionStream (needs Chrome 80+, Firefox 113+, Safari 16.4+)");
    }
    const bin = atob(blob.z);
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"));
    const buf = await new Response(stream).arrayBuffer();
    const arr = new TYPES[blob.dtype](buf);
    if (arr.length !== blob.n) throw new Error("embedded array has " + arr.length + " values, expected " + blob.n);
    blob._arr = arr;
    return arr;
  }

  // ---------------------------------------------------------------- colours (as report/colors.py)
  const GREY = [0.62, 0.62, 0.62];
  function positionColors(v, n) {
    const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    for (let i = 0; i < n; i++) for (let k = 0; k < 3; k++) {
      const x = v[3 * i + k];
      if (x < lo[k]) lo[k] = x;
      if (x > hi[k]) hi[k] = x;
    }
    const c = new Float32Array(3 * n);
    for (let i = 0; i < n; i++) for (let k = 0; k < 3; k++) {
      const span = hi[k] - lo[k] > 0 ? hi[k] - lo[k] : 1;
      c[3 * i + k] = 0.1 + 0.85 * (v[3 * i + k] - lo[k]) / span;
    }
    return c;
  }
  const VIRIDIS = [[0.267, 0.005, 0.329], [0.229, 0.322, 0.545], [0.128, 0.567, 0.551], [0.369, 0.789, 0.383], [0.993, 0.906, 0.144]];
  function ramp(t) {
    t = Math.min(Math.max(t, 0), 1) * (VIRIDIS.length - 1);
    const i = Math.min(Math.floor(t), VIRIDIS.length - 2), f = t - i;
    return [0, 1, 2].map((k) => VIRIDIS[i][k] * (1 - f) + VIRIDIS[i + 1][k] * f);
  }

  // ---------------------------------------------------------------- WebGL setup
  const canvas = $("viewer-canvas");
  const gl = canvas.getContext("webgl2", { preserveDrawingBuffer: true, antialias: true }) ||
    canvas.getContext("webgl", { preserveDrawingBuffer: true, antialias: true });
  if (!gl) {
    api.error = "WebGL unavailable";
    status.textContent = "This browser gives no WebGL context, so the 3D viewer cannot run; the tables and figures do not need it.";
    console.warn("topomatch viewer: no WebGL context");
    return;
  }
  const isGL2 = typeof WebGL2RenderingContext !== "undefined" && gl instanceof WebGL2RenderingContext;
  if (!isGL2 && !gl.getExtension("OES_element_index_uint")) {
    fail("WebGL lacks 32-bit indices (OES_element_index_uint)");
    return;
  }

  const VS_MESH = `
attribute vec3 aPos; attribute vec3 aNrm; attribute vec3 aCol;
uniform mat3 uR; uniform vec3 uC; uniform float uInvR; uniform vec2 uScale; uniform vec2 uPan; uniform float uZoom;
varying vec3 vCol; varying vec3 vN;
void main() {
  vec3 pc = uR * ((aPos - uC) * uInvR);
  gl_Position = vec4((pc.xy * uZoom + uPan) * uScale, -pc.z * 0.5, 1.0);
  vN = uR * aNrm; vCol = aCol;
}`;
  const FS_MESH = `
precision mediump float;
varying vec3 vCol; varying vec3 vN; uniform vec3 uL;
void main() {
  float l = length(vN) > 0.0 ? abs(dot(normalize(vN), uL)) : 0.5;
  gl_FragColor = vec4(vCol * (0.35 + 0.65 * l), 1.0);
}`;
  const VS_PTS = `
attribute vec3 aPos;
uniform mat3 uR; uniform vec3 uC; uniform float uInvR; uniform vec2 uScale; uniform vec2 uPan; uniform float uZoom; uniform float uSize;
void main() {
  vec3 pc = uR * ((aPos - uC) * uInvR);
  gl_Position = vec4((pc.xy * uZoom + uPan) * uScale, 0.0, 1.0);
  gl_PointSize = uSize;
}`;
  const FS_PTS = `
precision mediump float;
uniform vec3 uColor;
void main() {
  float r = length(gl_PointCoord - vec2(0.5)) * 2.0;
  if (r > 1.0) discard;
  gl_FragColor = r > 0.6 ? vec4(0.0, 0.0, 0.0, 1.0) : vec4(uColor, 1.0);
}`;

  function program(vs, fs) {
    const p = gl.createProgram();
    for (const [type, src] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, fs]]) {
      const s = gl.createShader(type);
      gl.shaderSource(s, src);
      gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error("shader: " + gl.getShaderInfoLog(s));
      gl.attachShader(p, s);
    }
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error("program: " + gl.getProgramInfoLog(p));
    const loc = { p };
    const nA = gl.getProgramParameter(p, gl.ACTIVE_ATTRIBUTES), nU = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
    for (let i = 0; i < nA; i++) { const a = gl.getActiveAttrib(p, i); loc[a.name] = gl.getAttribLocation(p, a.name); }
    for (let i = 0; i < nU; i++) { const u = gl.getActiveUniform(p, i); loc[u.name] = gl.getUniformLocation(p, u.name); }
    return loc;
  }
  let meshProg, ptsProg;
  try {
    meshProg = program(VS_MESH, FS_MESH);
    ptsProg = program(VS_PTS, FS_PTS);
  } catch (err) {
    fail(String(err.message || err), err);
    return;
  }

  function buffer(data, target) {
    const b = gl.createBuffer();
    gl.bindBuffer(target || gl.ARRAY_BUFFER, b);
    gl.bufferData(target || gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
    return b;
  }

  // ---------------------------------------------------------------- shapes on the GPU
  const shapeCache = new Map();
  async function loadShape(group, name) {
    const key = group.name + "/" + name;
    if (shapeCache.has(key)) return shapeCache.get(key);
    const sd = group.shapes[name];
    const v = await decode(sd.vertices);
    const f0 = await decode(sd.faces);
    const f = f0 instanceof Uint32Array ? f0 : new Uint32Array(f0);
    const n = sd.n_vertices, m = sd.n_faces;
    const nrm = new Float32Array(3 * n);
    for (let t = 0; t < m; t++) {
      const a = 3 * f[3 * t], b = 3 * f[3 * t + 1], c = 3 * f[3 * t + 2];
      const ux = v[b] - v[a], uy = v[b + 1] - v[a + 1], uz = v[b + 2] - v[a + 2];
      const wx = v[c] - v[a], wy = v[c + 1] - v[a + 1], wz = v[c + 2] - v[a + 2];
      const nx = uy * wz - uz * wy, ny = uz * wx - ux * wz, nz = ux * wy - uy * wx;
      for (const i of [a, b, c]) { nrm[i] += nx; nrm[i + 1] += ny; nrm[i + 2] += nz; }
    }
    for (let i = 0; i < n; i++) {
      const l = Math.hypot(nrm[3 * i], nrm[3 * i + 1], nrm[3 * i + 2]) || 1;
      nrm[3 * i] /= l; nrm[3 * i + 1] /= l; nrm[3 * i + 2] /= l;
    }
    const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    for (let i = 0; i < n; i++) for (let k = 0; k < 3; k++) {
      lo[k] = Math.min(lo[k], v[3 * i + k]); hi[k] = Math.max(hi[k], v[3 * i + k]);
    }
    const centre = [0, 1, 2].map((k) => 0.5 * (lo[k] + hi[k]));
    let r = 0;
    for (let i = 0; i < n; i++) {
      r = Math.max(r, Math.hypot(v[3 * i] - centre[0], v[3 * i + 1] - centre[1], v[3 * i + 2] - centre[2]));
    }
    const shape = {
      name, n, m, v, f, centre, radius: r || 1,
      field: positionColors(v, n),
      pos: buffer(v), nrm: buffer(nrm), idx: buffer(f, gl.ELEMENT_ARRAY_BUFFER),
      col: gl.createBuffer(), marks: gl.createBuffer(), nMarks: 0,
    };
    shapeCache.set(key, shape);
    return shape;
  }

  // ---------------------------------------------------------------- camera (shared)
  const INIT_R = [1, 0, 0, 0, 0, 1, 0, -1, 0]; // rows: screen right = x, up = z, toward viewer = -y
  const cam = { R: INIT_R.slice(), zoom: 0.92, pan: [0, 0] };
  function rotate(axis, angle) {
    const [x, y, z] = axis, c = Math.cos(angle), s = Math.sin(angle), t = 1 - c;
    const Q = [t * x * x + c, t * x * y - s * z, t * x * z + s * y,
      t * x * y + s * z, t * y * y + c, t * y * z - s * x,
      t * x * z - s * y, t * y * z + s * x, t * z * z + c];
    const R = cam.R, out = new Array(9);
    for (let i = 0; i < 3; i++) for (let j = 0; j < 3; j++) {
      out[3 * i + j] = Q[3 * i] * R[j] + Q[3 * i + 1] * R[3 + j] + Q[3 * i + 2] * R[6 + j];
    }
    cam.R = out;
  }
  const colMajor = (R) => new Float32Array([R[0], R[3], R[6], R[1], R[4], R[7], R[2], R[5], R[8]]);

  // ---------------------------------------------------------------- state and drawing
  const S = { group: null, method: null, pair: null, mode: "corr", source: null, target: null, map: null, errors: null, pick: null };
  api.state = S;
  let pending = false;
  function requestDraw() {
    if (!pending) { pending = true; requestAnimationFrame(() => { pending = false; draw(); }); }
  }

  function sizeCanvas() {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(1, Math.round(canvas.clientWidth * dpr)), h = Math.max(1, Math.round(canvas.clientHeight * dpr));
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
  }
  function viewportScale(wv, h) {
    const a = wv / h;
    return a >= 1 ? [1 / a, 1] : [1, a];
  }

  function setCommon(prog, shape, scale) {
    gl.uniformMatrix3fv(prog.uR, false, colMajor(cam.R));
    gl.uniform3fv(prog.uC, shape.centre);
    gl.uniform1f(prog.uInvR, 1 / shape.radius);
    gl.uniform2fv(prog.uScale, scale);
    gl.uniform2fv(prog.uPan, cam.pan);
    gl.uniform1f(prog.uZoom, cam.zoom);
  }

  function drawShape(shape, x0, wv, h) {
    gl.viewport(x0, 0, wv, h);
    const scale = viewportScale(wv, h);
    gl.enable(gl.DEPTH_TEST);
    gl.useProgram(meshProg.p);
    setCommon(meshProg, shape, scale);
    const L = [-0.25, 0.35, 1], ln = Math.hypot(...L);
    gl.uniform3f(meshProg.uL, L[0] / ln, L[1] / ln, L[2] / ln);
    for (const [attr, buf] of [["aPos", shape.pos], ["aNrm", shape.nrm], ["aCol", shape.col]]) {
      gl.bindBuffer(gl.ARRAY_BUFFER, buf);
      gl.enableVertexAttribArray(meshProg[attr]);
      gl.vertexAttribPointer(meshProg[attr], 3, gl.FLOAT, false, 0, 0);
    }
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, shape.idx);
    gl.drawElements(gl.TRIANGLES, 3 * shape.m, gl.UNSIGNED_INT, 0);
    for (const attr of ["aPos", "aNrm", "aCol"]) gl.disableVertexAttribArray(meshProg[attr]);
    if (shape.nMarks > 0) {
      gl.disable(gl.DEPTH_TEST);
      gl.useProgram(ptsProg.p);
      setCommon(ptsProg, shape, scale);
      gl.uniform1f(ptsProg.uSize, (shape.nMarks > 1 ? 9 : 15) * (window.devicePixelRatio || 1));
      gl.uniform3fv(ptsProg.uColor, shape.markColor);
      gl.bindBuffer(gl.ARRAY_BUFFER, shape.marks);
      gl.enableVertexAttribArray(ptsProg.aPos);
      gl.vertexAttribPointer(ptsProg.aPos, 3, gl.FLOAT, false, 0, 0);
      gl.drawArrays(gl.POINTS, 0, shape.nMarks);
      gl.disableVertexAttribArray(ptsProg.aPos);
    }
  }

  function draw() {
    sizeCanvas();
    const W = canvas.width, H = canvas.height, wv = Math.floor(W / 2);
    gl.viewport(0, 0, W, H);
    gl.clearColor(0.97, 0.97, 0.98, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    if (!S.source || !S.target) return;
    drawShape(S.source, 0, wv, H);
    drawShape(S.target, wv, W - wv, H);
    api.draws += 1;
  }

  function setMarks(shape, verts, color) {
    const pts = new Float32Array(3 * verts.length);
    verts.forEach((vi, k) => { for (let j = 0; j < 3; j++) pts[3 * k + j] = shape.v[3 * vi + j]; });
    gl.bindBuffer(gl.ARRAY_BUFFER, shape.marks);
    gl.bufferData(gl.ARRAY_BUFFER, pts, gl.DYNAMIC_DRAW);
    shape.nMarks = verts.length;
    shape.markColor = color;
  }

  const UNMATCHED = (map) => (map instanceof Uint16Array ? 65535 : -1);

  function recolour() {
    const src = S.source, tgt = S.target, map = S.map, um = UNMATCHED(map);
    const sc = src.field.slice();
    const hit = new Uint8Array(src.n);
    for (let x = 0; x < tgt.n; x++) if (map[x] !== um) hit[map[x]] = 1;
    if (S.mode === "coverage") {
      for (let y = 0; y < src.n; y++) if (!hit[y]) for (let k = 0; k < 3; k++) sc[3 * y + k] = GREY[k];
    }
    const tc = new Float32Array(3 * tgt.n);
    for (let x = 0; x < tgt.n; x++) {
      let c;
      if (S.mode === "error") {
        const e = S.errors[x];
        c = e === 65535 ? GREY : ramp((e * UNIT) / 0.25);
      } else {
        const y = map[x];
        c = y === um ? GREY : [src.field[3 * y], src.field[3 * y + 1], src.field[3 * y + 2]];
      }
      tc[3 * x] = c[0]; tc[3 * x + 1] = c[1]; tc[3 * x + 2] = c[2];
    }
    gl.bindBuffer(gl.ARRAY_BUFFER, src.col);
    gl.bufferData(gl.ARRAY_BUFFER, sc, gl.DYNAMIC_DRAW);
    gl.bindBuffer(gl.ARRAY_BUFFER, tgt.col);
    gl.bufferData(gl.ARRAY_BUFFER, tc, gl.DYNAMIC_DRAW);
  }

  // ---------------------------------------------------------------- picking
  const PICK_COLOR = [1.0, 0.85, 0.0], MATCH_COLOR = [1.0, 0.0, 0.9];
  function clearPick() {
    S.pick = null;
    if (S.source) S.source.nMarks = 0;
    if (S.target) S.target.nMarks = 0;
    const info = $("pick-info");
    info.dataset.side = ""; info.dataset.vertex = ""; info.dataset.match = "";
    info.textContent = "Click a point on either shape to see its match.";
  }

  function pick(side, vertex) {
    const src = S.source, tgt = S.target, map = S.map, um = UNMATCHED(map);
    const info = $("pick-info");
    let match = [], text;
    if (side === "target") {
      const y = map[vertex];
      match = y === um ? [] : [y];
      setMarks(tgt, [vertex], PICK_COLOR);
      setMarks(src, match, MATCH_COLOR);
      const e = S.errors[vertex];
      text = "target " + tgt.name + " vertex " + vertex + (y === um ? ": unmatched" :
        " \u2192 source " + src.name + " vertex " + y) +
        (e === 65535 ? " (not scored)" : "; error " + (e * UNIT).toFixed(4) + " (fraction of sqrt(area))");
    } else {
      for (let x = 0; x < tgt.n; x++) if (map[x] === vertex) match.push(x);
      let exact = match.length > 0;
      if (!exact) {
        // nearest image: the target vertex whose image lies closest to the picked point
        let best = -1, bd = Infinity;
        const p = [src.v[3 * vertex], src.v[3 * vertex + 1], src.v[3 * vertex + 2]];
        for (let x = 0; x < tgt.n; x++) {
          const y = map[x];
          if (y === um) continue;
          const d = (src.v[3 * y] - p[0]) ** 2 + (src.v[3 * y + 1] - p[1]) ** 2 + (src.v[3 * y + 2] - p[2]) ** 2;
          if (d < bd) { bd = d; best = x; }
        }
        if (best >= 0) match = [best];
      }
      setMarks(src, [vertex], PICK_COLOR);
      setMarks(tgt, match.slice(0, 2000), MATCH_COLOR);
      text = "source " + src.name + " vertex " + vertex + (exact ?
        " \u2190 " + match.length + " target vertex" + (match.length > 1 ? "es" : "") + " (" + match.slice(0, 8).join(", ") + (match.length > 8 ? ", ..." : "") + ")" :
        (match.length ? ": no target vertex maps here; nearest image from target vertex " + match[0] + " (\u2192 source vertex " + map[match[0]] + ")" : ": the map reaches no source vertex"));
      match = exact ? match : [];
    }
    S.pick = { side, vertex, match };
    info.dataset.side = side;
    info.dataset.vertex = String(vertex);
    info.dataset.match = match.join(",");
    info.textContent = text;
    requestDraw();
    return S.pick;
  }

  function cameraRay(side, cssX, cssY) {
    const rect = canvas.getBoundingClientRect();
    const wv = rect.width / 2, h = rect.height;
    const lx = cssX - (side === "target" ? wv : 0);
    const scale = viewportScale(wv, h);
    const nx = (lx / wv) * 2 - 1, ny = 1 - (cssY / h) * 2;
    return [(nx / scale[0] - cam.pan[0]) / cam.zoom, (ny / scale[1] - cam.pan[1]) / cam.zoom];
  }

  function pickAt(cssX, cssY) {
    const rect = canvas.getBoundingClientRect();
    const side = cssX < rect.width / 2 ? "source" : "target";
    const shape = side === "source" ? S.source : S.target;
    if (!shape) return null;
    const [px, py] = cameraRay(side, cssX, cssY);
    const R = cam.R, r = shape.radius, c = shape.centre;
    // camera -> model: p = c + r * R^T pc
    const toModel = (q) => [0, 1, 2].map((k) => c[k] + r * (R[k] * q[0] + R[3 + k] * q[1] + R[6 + k] * q[2]));
    const o = toModel([px, py, 10]);
    const d = [-R[6], -R[7], -R[8]];
    const v = shape.v, f = shape.f;
    let bestT = Infinity, bestF = -1;
    for (let t = 0; t < shape.m; t++) {
      const a = 3 * f[3 * t], b = 3 * f[3 * t + 1], cc = 3 * f[3 * t + 2];
      const e1x = v[b] - v[a], e1y = v[b + 1] - v[a + 1], e1z = v[b + 2] - v[a + 2];
      const e2x = v[cc] - v[a], e2y = v[cc + 1] - v[a + 1], e2z = v[cc + 2] - v[a + 2];
      const hx = d[1] * e2z - d[2] * e2y, hy = d[2] * e2x - d[0] * e2z, hz = d[0] * e2y - d[1] * e2x;
      const det = e1x * hx + e1y * hy + e1z * hz;
      if (Math.abs(det) < 1e-12) continue;
      const inv = 1 / det;
      const sx = o[0] - v[a], sy = o[1] - v[a + 1], sz = o[2] - v[a + 2];
      const u = (sx * hx + sy * hy + sz * hz) * inv;
      if (u < 0 || u > 1) continue;
      const qx = sy * e1z - sz * e1y, qy = sz * e1x - sx * e1z, qz = sx * e1y - sy * e1x;
      const w = (d[0] * qx + d[1] * qy + d[2] * qz) * inv;
      if (w < 0 || u + w > 1) continue;
      const tt = (e2x * qx + e2y * qy + e2z * qz) * inv;
      if (tt > 0 && tt < bestT) { bestT = tt; bestF = t; }
    }
    if (bestF < 0) return null;
    const hit = [o[0] + bestT * d[0], o[1] + bestT * d[1], o[2] + bestT * d[2]];
    let vert = -1, bd = Infinity;
    for (let k = 0; k < 3; k++) {
      const vi = f[3 * bestF + k];
      const dd = (v[3 * vi] - hit[0]) ** 2 + (v[3 * vi + 1] - hit[1]) ** 2 + (v[3 * vi + 2] - hit[2]) ** 2;
      if (dd < bd) { bd = dd; vert = vi; }
    }
    return pick(side, vert);
  }

  // Where a vertex is drawn, in client (CSS) coordinates: for tests and tooling.
  function project(side, vertex) {
    const shape = side === "source" ? S.source : S.target;
    const rect = canvas.getBoundingClientRect();
    const wv = rect.width / 2, h = rect.height, R = cam.R;
    const q = [0, 1, 2].map((k) => (shape.v[3 * vertex + k] - shape.centre[k]) / shape.radius);
    const pc = [0, 1, 2].map((i) => R[3 * i] * q[0] + R[3 * i + 1] * q[1] + R[3 * i + 2] * q[2]);
    const scale = viewportScale(wv, h);
    const nx = (pc[0] * cam.zoom + cam.pan[0]) * scale[0], ny = (pc[1] * cam.zoom + cam.pan[1]) * scale[1];
    return { x: rect.left + (side === "target" ? wv : 0) + (nx + 1) / 2 * wv, y: rect.top + (1 - ny) / 2 * h };
  }

  // ---------------------------------------------------------------- controls
  const selGroup = $("sel-group"), selMethod = $("sel-method"), selPair = $("sel-pair"), selColour = $("sel-colour");
  const group = () => DATA.groups[Number(selGroup.value)];
  const method = () => group().methods[Number(selMethod.value)];
  function option(sel, value, text, disabled) {
    const o = document.createElement("option");
    o.value = value; o.textContent = text; o.disabled = !!disabled;
    sel.appendChild(o);
  }
  DATA.groups.forEach((g, i) => option(selGroup, i, g.name + " (" + g.protocol + ")"));

  function fillMethods() {
    selMethod.innerHTML = "";
    group().methods.forEach((m, i) => option(selMethod, i, m.label + (m.auc_mean == null ? "" : " - AUC " + m.auc_mean.toFixed(3))));
  }
  function fillPairs(keep) {
    const m = method(), g = group();
    selPair.innerHTML = "";
    for (const p of g.pairs) {
      const e = m.pairs[p];
      option(selPair, p, p + (e && e.auc != null ? " (AUC " + e.auc.toFixed(3) + ")" : " (no map)"), !e);
    }
    const first = g.pairs.find((p) => m.pairs[p]);
    selPair.value = keep && m.pairs[keep] ? keep : first;
  }
  function extreme(best) {
    const m = method();
    let chosen = null, val = best ? -Infinity : Infinity;
    for (const [p, e] of Object.entries(m.pairs)) {
      if (e.auc == null) continue;
      if (best ? e.auc > val : e.auc < val) { val = e.auc; chosen = p; }
    }
    return chosen;
  }

  let loading = Promise.resolve();
  async function show() {
    const g = group(), m = method(), pid = selPair.value, entry = m.pairs[pid];
    if (!entry) return;
    const [tName, sName] = pid.split("-");
    status.textContent = "loading " + pid + "...";
    status.style.display = "block";
    const [source, target, map, errors] = await Promise.all([
      loadShape(g, sName), loadShape(g, tName), decode(entry.map), decode(entry.errors),
    ]);
    if (map.length !== target.n) throw new Error("map of " + pid + " has " + map.length + " entries for " + target.n + " target vertices");
    Object.assign(S, { group: g.name, method: m.method, label: m.label, pair: pid, source, target, map, errors });
    recolour();
    clearPick();
    $("label-source").textContent = "source " + sName + " (" + source.n + " vertices)";
    $("label-target").textContent = "target " + tName + " (" + target.n + " vertices)";
    $("pair-info").textContent = m.label + " on " + pid + ": AUC " + (entry.auc == null ? "-" : entry.auc.toFixed(3)) +
      ", mean error " + (entry.mean_error == null ? "-" : entry.mean_error.toFixed(4)) +
      ", area matched " + (entry.area_matched == null ? "-" : (100 * entry.area_matched).toFixed(1) + "%") +
      (entry.symmetric_used ? " (scored against the mirrored ground truth)" : "") +
      (g.pairs.length < g.n_pairs_total ? ". " + (g.n_pairs_total - g.pairs.length) + " of " + g.n_pairs_total + " pairs are not embedded (size budget)." : "");
    status.style.display = "none";
    requestDraw();
  }
  function update(fn) {
    loading = loading.then(fn).then(show).catch((err) => fail(String(err.message || err), err));
    return loading;
  }

  selGroup.addEventListener("change", () => update(() => { fillMethods(); fillPairs(); }));
  selMethod.addEventListener("change", () => update(() => fillPairs(selPair.value)));
  selPair.addEventListener("change", () => update(() => {}));
  selColour.addEventListener("change", () => { S.mode = selColour.value; if (S.map) { recolour(); requestDraw(); } });
  $("btn-best").addEventListener("click", () => update(() => { const p = extreme(true); if (p) selPair.value = p; }));
  $("btn-worst").addEventListener("click", () => update(() => { const p = extreme(false); if (p) selPair.value = p; }));
  $("btn-reset").addEventListener("click", () => { cam.R = INIT_R.slice(); cam.zoom = 0.92; cam.pan = [0, 0]; requestDraw(); });

  // mouse: drag rotates, shift- or right-drag pans, wheel zooms, a click picks
  let drag = null;
  canvas.addEventListener("contextmenu", (ev) => ev.preventDefault());
  canvas.addEventListener("pointerdown", (ev) => {
    drag = { x: ev.clientX, y: ev.clientY, x0: ev.clientX, y0: ev.clientY, pan: ev.shiftKey || ev.button === 2 };
    canvas.setPointerCapture(ev.pointerId);
  });
  canvas.addEventListener("pointermove", (ev) => {
    if (!drag) return;
    const dx = ev.clientX - drag.x, dy = ev.clientY - drag.y;
    drag.x = ev.clientX; drag.y = ev.clientY;
    if (drag.pan) {
      const rect = canvas.getBoundingClientRect(), scale = viewportScale(rect.width / 2, rect.height);
      cam.pan[0] += (2 * dx) / (rect.width / 2) / scale[0];
      cam.pan[1] -= (2 * dy) / rect.height / scale[1];
    } else {
      if (dx) rotate([0, 1, 0], dx * 0.01);
      if (dy) rotate([1, 0, 0], dy * 0.01);
    }
    requestDraw();
  });
  canvas.addEventListener("pointerup", (ev) => {
    if (!drag) return;
    const moved = Math.hypot(ev.clientX - drag.x0, ev.clientY - drag.y0);
    drag = null;
    if (moved < 4 && ev.button === 0) {
      const rect = canvas.getBoundingClientRect();
      if (!pickAt(ev.clientX - rect.left, ev.clientY - rect.top)) clearPick(), requestDraw();
    }
  });
  canvas.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    cam.zoom = Math.min(50, Math.max(0.1, cam.zoom * Math.exp(-ev.deltaY * 0.0015)));
    requestDraw();
  }, { passive: false });
  window.addEventListener("resize", requestDraw);

  // ---------------------------------------------------------------- test / scripting hook
  api.select = (groupIndex, methodIndex, pair) => update(() => {
    selGroup.value = String(groupIndex); fillMethods();
    selMethod.value = String(methodIndex); fillPairs(pair);
  });
  api.pick = (side, vertex) => pick(side, vertex);
  api.project = project;
  api.camera = cam;
  api.redraw = () => { draw(); return api.draws; };

  fillMethods();
  const first = method();
  fillPairs();
  const best = extreme(true);
  if (best && first) selPair.value = best;
  update(() => {}).then(() => { api.ready = !api.error; });
})();
