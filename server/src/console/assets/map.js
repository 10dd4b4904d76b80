// The live top-down map: server-drawn tiles (PNG per 4x4 chunk columns,
// redrawn by the server when a chunk changes) on a canvas with pan and
// zoom, player markers, flashes where edits land (coloured by kind),
// protected zones as outlines and, on a cluster node, who writes each
// region (tinted by node, refreshed every few seconds).
"use strict";

const StrataMap = (() => {
  const KIND_COLOURS = {
    mine: "#ff5040", explode: "#ffb000", build: "#40c0ff",
    fill_box: "#c070ff", clear_box: "#c070ff", place_structure: "#ffffff", smooth: "#ffffff",
  };
  const FLASH_MS = 2500;
  const MAX_INFLIGHT = 4;
  const REGIONS_EVERY_MS = 2000;
  const MAX_REGIONS = 1024;
  // Tiles kept (about 64 KB each); the least recently shown go first.
  const MAX_TILES = 1024;
  let world, canvas, ctx;
  let cx = 0, cz = 0, scale = 1, follow = true;
  let view = "top", sliceY = 0;
  const tiles = new Map();
  let inflight = 0;
  let players = [], zones = [], flashes = [];
  let regions = [], regionsAt = 0, regionsBox = "", regionsLoading = false;

  const tileVoxels = () => world.tile_voxels;
  const key = (tx, tz) => `${view}:${view === "slice" ? sliceY : ""}:${tx}:${tz}`;

  function toScreen(x, z) {
    return [(x - cx) * scale + canvas.width / 2, (z - cz) * scale + canvas.height / 2];
  }
  function toWorld(px, py) {
    return [(px - canvas.width / 2) / scale + cx, (py - canvas.height / 2) / scale + cz];
  }

  function visibleTiles() {
    const [x0, z0] = toWorld(0, 0);
    const [x1, z1] = toWorld(canvas.width, canvas.height);
    const t = tileVoxels();
    const out = [];
    for (let tz = Math.floor(z0 / t); tz <= Math.floor(z1 / t); tz++)
      for (let tx = Math.floor(x0 / t); tx <= Math.floor(x1 / t); tx++) out.push([tx, tz]);
    return out;
  }

  async function fetchTile(tx, tz, entry) {
    inflight++;
    entry.loading = true;
    const wanted = entry.gen;
    const params = view === "slice" ? `view=slice&y=${sliceY}` : "view=top";
    try {
      const resp = await api(`/api/tile?${params}&tx=${tx}&tz=${tz}&v=${wanted}`);
      if (resp.ok) {
        entry.img = await createImageBitmap(await resp.blob());
        entry.drawn = wanted;
      } else {
        entry.retryAt = Date.now() + 1000;
      }
    } catch (e) {
      entry.retryAt = Date.now() + 2000;
    }
    entry.loading = false;
    inflight--;
    draw();
  }

  function loadTiles(list) {
    const now = Date.now();
    const shown = new Set();
    for (const [tx, tz] of list) {
      const k = key(tx, tz);
      shown.add(k);
      let e = tiles.get(k);
      if (e) tiles.delete(k); else e = { gen: 0, drawn: -1 };
      tiles.set(k, e); // the newest shown last
      if (inflight < MAX_INFLIGHT && !e.loading && e.drawn !== e.gen && !(e.retryAt > now))
        fetchTile(tx, tz, e);
    }
    for (const [k, e] of tiles) {
      if (tiles.size <= MAX_TILES) break;
      if (shown.has(k) || e.loading) continue;
      if (e.img) e.img.close();
      tiles.delete(k);
    }
  }

  // The chunk columns in view, or null when zoomed out past MAX_REGIONS.
  function regionQuery() {
    const [x0, z0] = toWorld(0, 0);
    const [x1, z1] = toWorld(canvas.width, canvas.height);
    const ch = (v) => Math.floor(v / 32);
    const side = world.region_chunks;
    const n = (Math.floor(ch(x1) / side) - Math.floor(ch(x0) / side) + 1) *
      (Math.floor(ch(z1) / side) - Math.floor(ch(z0) / side) + 1);
    if (n > MAX_REGIONS) return null;
    return `x0=${ch(x0)}&z0=${ch(z0)}&x1=${ch(x1)}&z1=${ch(z1)}`;
  }

  async function loadRegions() {
    if (!world.clustered || regionsLoading) return;
    const q = regionQuery();
    if (q === null) { regions = []; showOwners(); return; }
    if (q === regionsBox && Date.now() - regionsAt < REGIONS_EVERY_MS) return;
    regionsLoading = true;
    try {
      const resp = await api(`/api/regions?${q}`);
      if (resp.ok) {
        regions = (await resp.json()).regions;
        regionsBox = q;
      }
    } catch (e) { /* the next draw asks again */ }
    regionsAt = Date.now();
    regionsLoading = false;
    showOwners();
  }

  // A steady colour per node name, never the zones' yellow (hues 40-80).
  function nodeColour(name) {
    let h = 0;
    for (const c of name) h = (h * 31 + c.codePointAt(0)) % 320;
    return `hsl(${h < 40 ? h : h + 40}, 70%, 55%)`;
  }

  function owner(r) {
    if (r.holder === "here") return world.node_id || "this node";
    return r.holder === "node" ? r.node : "";
  }

  function showOwners() {
    const legend = document.getElementById("region-legend");
    const names = [...new Set(regions.map(owner).filter((n) => n))].sort();
    legend.replaceChildren(...names.map((n) => {
      const span = document.createElement("span");
      span.className = "owner";
      span.dataset.node = n;
      span.style.borderColor = nodeColour(n);
      span.textContent = n;
      return span;
    }));
  }

  function drawRegions() {
    const side = world.region_chunks * 32;
    let drawn = 0;
    ctx.lineWidth = 1;
    for (const r of regions) {
      const [sx, sy] = toScreen(r.x * side, r.z * side);
      const w = side * scale;
      const name = owner(r);
      ctx.setLineDash(name ? [] : [4, 4]);
      ctx.strokeStyle = name ? nodeColour(name) : "#888";
      if (name) {
        ctx.globalAlpha = 0.15;
        ctx.fillStyle = nodeColour(name);
        ctx.fillRect(sx, sy, w, w);
        ctx.globalAlpha = 1;
      }
      ctx.strokeRect(sx + 0.5, sy + 0.5, w - 1, w - 1);
      ctx.fillStyle = name ? nodeColour(name) : "#888";
      ctx.fillText(name || "free", sx + 3, sy + w - 4);
      drawn++;
    }
    ctx.setLineDash([]);
    canvas.dataset.regions = drawn;
  }

  function zoneBox(z) {
    const v = (p) => (Array.isArray(p) ? p : [p.x, p.y, p.z]);
    return [v(z.min), v(z.max)];
  }

  function draw() {
    if (!ctx) return;
    ctx.imageSmoothingEnabled = false;
    ctx.fillStyle = "#000";
    ctx.fillRect(0, 0, canvas.width, canvas.height);
    const list = visibleTiles();
    let drawn = 0;
    const t = tileVoxels();
    for (const [tx, tz] of list) {
      const e = tiles.get(key(tx, tz));
      if (!e || !e.img) continue;
      const [sx, sy] = toScreen(tx * t, tz * t);
      ctx.drawImage(e.img, sx, sy, t * scale, t * scale);
      drawn++;
    }
    loadTiles(list);
    if (world.clustered) {
      drawRegions();
      loadRegions();
    }
    ctx.lineWidth = 2;
    ctx.strokeStyle = "#ff2";
    for (const z of zones) {
      const [a, b] = zoneBox(z);
      const [sx, sy] = toScreen(a[0], a[2]);
      ctx.strokeRect(sx, sy, (b[0] - a[0] + 1) * scale, (b[2] - a[2] + 1) * scale);
      ctx.fillStyle = "#ff2";
      ctx.fillText(z.name, sx + 2, sy + 12);
    }
    const now = Date.now();
    flashes = flashes.filter((f) => now - f.t < FLASH_MS);
    for (const f of flashes) {
      const age = (now - f.t) / FLASH_MS;
      const [sx, sy] = toScreen(f.at[0], f.at[2]);
      ctx.globalAlpha = 1 - age;
      ctx.strokeStyle = KIND_COLOURS[f.kind] || "#fff";
      ctx.beginPath();
      ctx.arc(sx, sy, 4 + 14 * age, 0, 2 * Math.PI);
      ctx.stroke();
    }
    ctx.globalAlpha = 1;
    let markers = 0;
    for (const p of players) {
      if (!p.at) continue;
      const [sx, sy] = toScreen(p.at[0], p.at[2]);
      ctx.fillStyle = "#0f0";
      ctx.strokeStyle = "#000";
      ctx.beginPath();
      ctx.arc(sx, sy, 5, 0, 2 * Math.PI);
      ctx.fill();
      ctx.stroke();
      ctx.fillStyle = "#fff";
      ctx.fillText(p.player, sx + 7, sy - 7);
      markers++;
    }
    canvas.dataset.tilesDrawn = drawn;
    canvas.dataset.markers = markers;
    canvas.dataset.flashes = flashes.length;
  }

  function onSample(s) {
    players = s.players;
    zones = s.zones;
    const now = Date.now();
    for (const e of s.edits) flashes.push({ at: e.at, kind: e.kind, t: now });
    const c = world.tile_columns;
    // Samples were missed: which columns changed is unknown, so all.
    if (s.lagged) for (const [, e] of tiles) e.gen++;
    for (const [x, z] of s.columns) {
      for (const v of ["top", "slice"]) {
        for (const [k, e] of tiles) {
          if (k.startsWith(v + ":") && k.endsWith(`:${Math.floor(x / c)}:${Math.floor(z / c)}`)) e.gen++;
        }
      }
    }
    if (follow) {
      const placed = players.filter((p) => p.at);
      if (placed.length) {
        cx = placed.reduce((a, p) => a + p.at[0], 0) / placed.length;
        cz = placed.reduce((a, p) => a + p.at[2], 0) / placed.length;
      }
    }
    draw();
  }

  function bind() {
    let drag = null;
    canvas.addEventListener("mousedown", (e) => {
      drag = { x: e.offsetX, y: e.offsetY, shift: e.shiftKey, ctrl: e.ctrlKey, cx, cz };
    });
    window.addEventListener("mouseup", (e) => {
      if (drag && (drag.shift || drag.ctrl)) {
        const [ax, az] = toWorld(drag.x, drag.y);
        const [bx, bz] = toWorld(e.offsetX, e.offsetY);
        const [x0, z0, x1, z1] = [Math.min(ax, bx), Math.min(az, bz), Math.max(ax, bx), Math.max(az, bz)]
          .map(Math.floor);
        if (drag.ctrl) {
          // A zone drawn on the map, over the world's whole height: the
          // operator names it and confirms with "Add zone".
          document.getElementById("zone-box").value =
            `${x0} ${world.min_y} ${z0} ${x1} ${world.max_y} ${z1}`;
          document.getElementById("zone-name").focus();
        } else {
          const ch = (v) => Math.floor(v / 32);
          StrataView3d.setRegion(ch(x0), ch(z0), ch(x1), ch(z1));
        }
      }
      drag = null;
    });
    canvas.addEventListener("mousemove", (e) => {
      const [x, z] = toWorld(e.offsetX, e.offsetY);
      document.getElementById("cursor").textContent = `x ${x.toFixed(0)} z ${z.toFixed(0)}`;
      if (drag && !drag.shift && !drag.ctrl) {
        follow = false;
        cx = drag.cx - (e.offsetX - drag.x) / scale;
        cz = drag.cz - (e.offsetY - drag.y) / scale;
        draw();
      }
    });
    canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      scale = Math.min(8, Math.max(0.125, scale * (e.deltaY < 0 ? 1.25 : 0.8)));
      draw();
    });
    for (const r of document.querySelectorAll("input[name=view]")) {
      r.addEventListener("change", () => { view = r.value; draw(); });
    }
    const y = document.getElementById("slice-y");
    y.addEventListener("change", () => { sliceY = Number(y.value) | 0; if (view === "slice") draw(); });
  }

  function start(w) {
    world = w;
    canvas = document.getElementById("map");
    ctx = canvas.getContext("2d");
    ctx.font = "11px sans-serif";
    document.getElementById("region-bar").hidden = !world.clustered;
    bind();
    draw();
    setInterval(draw, 250);
  }

  return { start, onSample };
})();
