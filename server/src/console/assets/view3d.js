// The 3-D view: a region's welded LOD-0 mesh as binary glTF from
// /api/scene.glb, parsed here and drawn with WebGL2 (orbit with the mouse,
// zoom with the wheel). Without WebGL2 the panel says so and the rest of
// the console works as before.
//
// #scene-state's data-state: "idle", "loading", "error", "no-webgl2" (set at
// start, before any fetch), and after a fetched glTF parsed "drawn" or, with
// no WebGL2 to draw it, "parsed-no-webgl2"; those two set data-triangles to
// the parsed mesh's triangle count.
"use strict";

const StrataView3d = (() => {
  let world, canvas, gl = null, prog, mesh = null;
  let region = null;
  let yaw = 0.8, pitch = 0.6, dist = 200;
  const state = (s, text, triangles) => {
    const el = document.getElementById("scene-state");
    el.dataset.state = s;
    if (triangles === undefined) delete el.dataset.triangles;
    else el.dataset.triangles = String(triangles);
    el.textContent = text || s;
  };

  const VS = `#version 300 es
    in vec3 p; in vec3 n; in vec4 c;
    uniform mat4 mvp; out vec3 vn; out vec4 vc;
    void main() { gl_Position = mvp * vec4(p, 1.0); vn = n; vc = c; }`;
  const FS = `#version 300 es
    precision mediump float; in vec3 vn; in vec4 vc; out vec4 o;
    void main() {
      float l = 0.35 + 0.65 * max(dot(normalize(vn), normalize(vec3(0.4, 1.0, 0.3))), 0.0);
      o = vec4(vc.rgb * l, 1.0);
    }`;

  function compile(type, src) {
    const s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
    return s;
  }

  // GLB: 12-byte header, a JSON chunk, a BIN chunk.
  function parseGlb(buf) {
    const dv = new DataView(buf);
    if (dv.getUint32(0, true) !== 0x46546c67) throw new Error("not a GLB file");
    const jsonLen = dv.getUint32(12, true);
    const doc = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 20, jsonLen)));
    const binStart = 20 + jsonLen + 8;
    const prim = doc.meshes[0].primitives[0];
    const view = (acc, Type, comps) => {
      const a = doc.accessors[acc];
      const bv = doc.bufferViews[a.bufferView];
      const off = binStart + (bv.byteOffset || 0) + (a.byteOffset || 0);
      return { data: new Type(buf, off, a.count * comps), count: a.count, min: a.min, max: a.max };
    };
    return {
      pos: view(prim.attributes.POSITION, Float32Array, 3),
      nrm: view(prim.attributes.NORMAL, Float32Array, 3),
      col: view(prim.attributes.COLOR_0, Uint8Array, 4),
      idx: view(prim.indices, Uint32Array, 1),
    };
  }

  function upload(m) {
    const vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    const attr = (name, arr, size, type, norm) => {
      const b = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, b);
      gl.bufferData(gl.ARRAY_BUFFER, arr, gl.STATIC_DRAW);
      const loc = gl.getAttribLocation(prog, name);
      gl.enableVertexAttribArray(loc);
      gl.vertexAttribPointer(loc, size, type, norm, 0, 0);
    };
    attr("p", m.pos.data, 3, gl.FLOAT, false);
    attr("n", m.nrm.data, 3, gl.FLOAT, false);
    attr("c", m.col.data, 4, gl.UNSIGNED_BYTE, true);
    const ib = gl.createBuffer();
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ib);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, m.idx.data, gl.STATIC_DRAW);
    const min = m.pos.min || [0, 0, 0], max = m.pos.max || [1, 1, 1];
    const centre = [0, 1, 2].map((i) => (min[i] + max[i]) / 2);
    dist = Math.max(max[0] - min[0], max[2] - min[2]) * 1.3 + 20;
    return { vao, count: m.idx.count, centre };
  }

  function matMul(a, b) {
    const o = new Float32Array(16);
    for (let i = 0; i < 4; i++)
      for (let j = 0; j < 4; j++) {
        let s = 0;
        for (let k = 0; k < 4; k++) s += a[k * 4 + j] * b[i * 4 + k];
        o[i * 4 + j] = s;
      }
    return o;
  }

  function mvp() {
    const aspect = canvas.width / canvas.height, f = 1 / Math.tan(0.5), near = 1, far = 5000;
    const proj = new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) / (near - far), -1,
      0, 0, (2 * far * near) / (near - far), 0]);
    const c = mesh.centre;
    const eye = [c[0] + dist * Math.cos(pitch) * Math.sin(yaw), c[1] + dist * Math.sin(pitch),
      c[2] + dist * Math.cos(pitch) * Math.cos(yaw)];
    const norm = (v) => { const l = Math.hypot(...v); return v.map((x) => x / l); };
    const sub = (a, b) => a.map((x, i) => x - b[i]);
    const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    const zf = norm(sub(eye, c)), xr = norm(cross([0, 1, 0], zf)), yu = cross(zf, xr);
    const view = new Float32Array([xr[0], yu[0], zf[0], 0, xr[1], yu[1], zf[1], 0, xr[2], yu[2], zf[2], 0,
      -dot(xr, eye), -dot(yu, eye), -dot(zf, eye), 1]);
    return matMul(proj, view);
  }

  function draw() {
    if (!gl || !mesh) return;
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.clearColor(0.05, 0.06, 0.08, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    gl.useProgram(prog);
    gl.uniformMatrix4fv(gl.getUniformLocation(prog, "mvp"), false, mvp());
    gl.bindVertexArray(mesh.vao);
    gl.drawElements(gl.TRIANGLES, mesh.count, gl.UNSIGNED_INT, 0);
  }

  async function load() {
    if (!region) { state("idle", "pick a region: shift-drag on the map"); return; }
    const [x0, z0, x1, z1, y0, y1] = region;
    const rows = y0 === undefined ? "" : `&y0=${y0}&y1=${y1}`;
    state("loading");
    const resp = await api(`/api/scene.glb?x0=${x0}&z0=${z0}&x1=${x1}&z1=${z1}${rows}`);
    if (!resp.ok) {
      const body = await resp.json().catch(() => ({}));
      state("error", "refused: " + (body.error || resp.status));
      return;
    }
    const parsed = parseGlb(await resp.arrayBuffer());
    const triangles = Math.floor(parsed.idx.count / 3);
    if (!gl) {
      state("parsed-no-webgl2", `${triangles} triangles (no WebGL2 here to draw them)`, triangles);
      return;
    }
    mesh = upload(parsed);
    state("drawn", `${triangles} triangles`, triangles);
    draw();
  }

  function setRegion(x0, z0, x1, z1, y0, y1) {
    region = [x0, z0, x1, z1, y0, y1];
    const ys = y0 === undefined ? "" : `, y ${y0}..${y1}`;
    document.getElementById("scene-box").textContent = `x ${x0}..${x1}, z ${z0}..${z1}${ys}`;
  }

  // The 3x3 chunk columns around the players, a few rows about their feet.
  function around(players) {
    const placed = players.filter((p) => p.at);
    if (!placed.length) return;
    const mean = (i) => placed.reduce((a, p) => a + p.at[i], 0) / placed.length;
    const [cx, cy, cz] = [0, 1, 2].map((i) => Math.floor(mean(i) / 32));
    setRegion(cx - 1, cz - 1, cx + 1, cz + 1, cy - 2, cy + 1);
    load();
  }

  function start(w) {
    world = w;
    canvas = document.getElementById("view3d");
    setRegion(-1, -1, 1, 1);
    try {
      gl = canvas.getContext("webgl2");
      if (gl) {
        prog = gl.createProgram();
        gl.attachShader(prog, compile(gl.VERTEX_SHADER, VS));
        gl.attachShader(prog, compile(gl.FRAGMENT_SHADER, FS));
        gl.linkProgram(prog);
      }
    } catch (e) {
      gl = null;
    }
    state(gl ? "idle" : "no-webgl2", gl ? "ready" : "WebGL2 is not available: the 3-D view is off");
    document.getElementById("scene-load").onclick = load;
    let drag = null;
    canvas.addEventListener("mousedown", (e) => { drag = { x: e.offsetX, y: e.offsetY, yaw, pitch }; });
    window.addEventListener("mouseup", () => { drag = null; });
    canvas.addEventListener("mousemove", (e) => {
      if (!drag) return;
      yaw = drag.yaw - (e.offsetX - drag.x) * 0.01;
      pitch = Math.max(-1.4, Math.min(1.4, drag.pitch + (e.offsetY - drag.y) * 0.01));
      draw();
    });
    canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      dist *= e.deltaY < 0 ? 0.85 : 1.15;
      draw();
    });
  }

  return { start, setRegion, around };
})();
