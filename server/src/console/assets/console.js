// The console's glue: sign-in, the authenticated fetch helper, the live
// event stream (fetch streaming, since EventSource cannot send a header),
// and the admin actions (each confirmed by the operator first).
"use strict";

const Console = {
  token: null,
  world: null,
  lastSample: null,
};

function authHeaders(extra) {
  return Object.assign({ Authorization: "Bearer " + Console.token }, extra || {});
}

async function api(path, options) {
  const opts = Object.assign({}, options || {});
  opts.headers = authHeaders(opts.headers);
  return fetch(path, opts);
}

function setStatus(state, text) {
  const el = document.getElementById("status");
  el.dataset.state = state;
  el.textContent = text;
}

function logAction(text) {
  const el = document.getElementById("act-log");
  el.textContent = new Date().toLocaleTimeString() + " " + text + "\n" + el.textContent;
}

// Reads `event:`/`data:` blocks from a streamed response body.
async function readEvents(resp, onEvent) {
  const reader = resp.body.getReader();
  const decoder = new TextDecoder();
  let buf = "";
  for (;;) {
    const { value, done } = await reader.read();
    if (done) return;
    buf += decoder.decode(value, { stream: true });
    let end;
    while ((end = buf.indexOf("\n\n")) >= 0) {
      const block = buf.slice(0, end);
      buf = buf.slice(end + 2);
      let name = "message";
      const data = [];
      for (const line of block.split("\n")) {
        if (line.startsWith("event:")) name = line.slice(6).trim();
        else if (line.startsWith("data:")) data.push(line.slice(5).replace(/^ /, ""));
      }
      if (data.length) onEvent(name, data.join("\n"));
    }
  }
}

async function watch() {
  for (;;) {
    try {
      const resp = await api("/api/events");
      if (!resp.ok) throw new Error("events: HTTP " + resp.status);
      setStatus("live", "live as " + Console.world.admin);
      await readEvents(resp, (name, data) => {
        if (name !== "sample") return;
        const s = JSON.parse(data);
        Console.lastSample = s;
        StrataMap.onSample(s);
        StrataCharts.onSample(s);
        showPlayers(s.players);
        showSnapshot(s.snapshot);
        if (!Console.sceneShown && s.players.some((p) => p.at)) {
          Console.sceneShown = true;
          StrataView3d.around(s.players);
        }
      });
      setStatus("error", "event stream ended; reconnecting");
    } catch (e) {
      setStatus("error", String(e));
    }
    await new Promise((r) => setTimeout(r, 2000));
  }
}

function showPlayers(players) {
  document.getElementById("player-count").textContent = players.length;
  const ul = document.getElementById("players");
  ul.replaceChildren(
    ...players.map((p) => {
      const li = document.createElement("li");
      const at = p.at ? p.at.map((v) => v.toFixed(0)).join(" ") : "-";
      li.textContent = `${p.player} (${p.role}) ${at}`;
      li.onclick = () => { document.getElementById("act-name").value = p.player; };
      return li;
    })
  );
}

function showSnapshot(s) {
  const bar = document.getElementById("snap-progress");
  const text = document.getElementById("snap-state");
  if (!s) return;
  bar.max = Math.max(1, s.total);
  bar.value = s.state === "done" ? bar.max : s.written;
  text.textContent = `${s.state} seq ${s.seq}: ${s.written}/${s.total} chunks` +
    (s.bytes ? `, ${s.bytes} bytes` : "") + (s.error ? ` (${s.error})` : "");
}

async function runAction(action, summary) {
  if (!window.confirm("Confirm: " + summary + "?")) return;
  const resp = await api("/api/action", {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify({ confirm: true, action }),
  });
  const body = await resp.json().catch(() => ({}));
  logAction(summary + ": " + (resp.ok ? JSON.stringify(body.ok) : "refused: " + body.error));
}

function bindActions() {
  document.getElementById("act-player").addEventListener("submit", (e) => {
    e.preventDefault();
    const player = document.getElementById("act-name").value.trim();
    const kind = e.submitter.dataset.action;
    const action = kind === "ban" ? { ban: { player, until: null } } : { [kind]: { player } };
    runAction(action, `${kind} ${player}`);
  });
  document.getElementById("act-zone").addEventListener("submit", (e) => {
    e.preventDefault();
    const name = document.getElementById("zone-name").value.trim();
    const kind = e.submitter.dataset.action;
    if (kind === "zone_remove") {
      runAction({ zone_remove: { name } }, `remove zone ${name}`);
      return;
    }
    const n = document.getElementById("zone-box").value.trim().split(/[\s,]+/).map(Number);
    if (n.length !== 6 || n.some((v) => !Number.isInteger(v))) {
      logAction("a zone needs six integers: x0 y0 z0 x1 y1 z1");
      return;
    }
    runAction({ zone_add: { name, min: n.slice(0, 3), max: n.slice(3) } },
      `add zone ${name} ${n.join(" ")}`);
  });
  document.getElementById("act-snapshot").addEventListener("submit", (e) => {
    e.preventDefault();
    runAction("snapshot", "start a snapshot");
  });
}

async function signIn(token) {
  Console.token = token;
  const resp = await api("/api/world");
  if (!resp.ok) {
    const body = await resp.json().catch(() => ({}));
    setStatus("error", "refused: " + (body.error || resp.status));
    return;
  }
  Console.world = await resp.json();
  sessionStorage.setItem("strata-token", token);
  document.getElementById("login").hidden = true;
  document.getElementById("app").hidden = false;
  StrataMap.start(Console.world);
  StrataCharts.start();
  StrataView3d.start(Console.world);
  bindActions();
  watch();
}

window.addEventListener("DOMContentLoaded", () => {
  const m = /(?:^#|&)token=([^&]+)/.exec(location.hash);
  if (m) {
    // Keep the token out of the address bar and history.
    history.replaceState(null, "", location.pathname);
  }
  const token = m ? decodeURIComponent(m[1]) : sessionStorage.getItem("strata-token");
  document.getElementById("login").addEventListener("submit", (e) => {
    e.preventDefault();
    signIn(document.getElementById("token").value.trim());
  });
  if (token) signIn(token);
});
