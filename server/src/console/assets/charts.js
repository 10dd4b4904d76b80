// Live line charts on canvases, fed by each sample: counters arrive as
// totals and are turned into rates here; latencies arrive as p50/p99.
"use strict";

const StrataCharts = (() => {
  const KEEP = 120;
  const PALETTE = ["#7c7", "#e77", "#fb4", "#6bf", "#c8f", "#fff", "#8dd", "#d88"];
  const charts = {};
  let prev = null;

  function chart(id) {
    const canvas = document.getElementById(id);
    return { canvas, ctx: canvas.getContext("2d"), series: new Map(), points: 0 };
  }

  function push(c, name, value) {
    if (value === null || value === undefined || !Number.isFinite(value)) return;
    if (!c.series.has(name)) c.series.set(name, []);
    const s = c.series.get(name);
    s.push(value);
    if (s.length > KEEP) s.shift();
    c.points++;
  }

  function draw(c) {
    const { ctx, canvas } = c;
    ctx.fillStyle = "#000";
    ctx.fillRect(0, 0, canvas.width, canvas.height);
    let max = 0;
    for (const s of c.series.values()) for (const v of s) max = Math.max(max, v);
    max = max > 0 ? max * 1.1 : 1;
    let i = 0;
    ctx.font = "10px sans-serif";
    for (const [name, s] of c.series) {
      const colour = PALETTE[i % PALETTE.length];
      ctx.strokeStyle = colour;
      ctx.beginPath();
      s.forEach((v, k) => {
        const x = (k / (KEEP - 1)) * canvas.width;
        const y = canvas.height - 12 - (v / max) * (canvas.height - 16);
        if (k === 0) ctx.moveTo(x, y); else ctx.lineTo(x, y);
      });
      ctx.stroke();
      ctx.fillStyle = colour;
      ctx.fillText(`${name} ${fmt(s[s.length - 1])}`, 4 + (i % 3) * 98, canvas.height - 2 - 10 * Math.floor(i / 3) );
      i++;
    }
    ctx.fillStyle = "#889";
    ctx.fillText(fmt(max), canvas.width - 40, 10);
    canvas.dataset.points = c.points;
  }

  function fmt(v) {
    if (v === undefined) return "";
    if (v >= 1e6) return (v / 1e6).toFixed(1) + "M";
    if (v >= 1e3) return (v / 1e3).toFixed(1) + "k";
    return v >= 10 ? v.toFixed(0) : v.toFixed(2);
  }

  const ms = (s) => (s === null || s === undefined ? null : s * 1000);

  function onSample(s) {
    const st = s.stats;
    push(charts.players, "players", s.players.length);
    if (prev) {
      const dt = Math.max(0.001, (s.time_ms - prev.time_ms) / 1000);
      push(charts.edits, "accepted", (st.edits_accepted - prev.stats.edits_accepted) / dt);
      for (const [reason, total] of Object.entries(st.edits_rejected)) {
        const before = prev.stats.edits_rejected[reason] || 0;
        push(charts.edits, reason, (total - before) / dt);
      }
      push(charts.bytes, "bytes/s", (st.bytes_out - prev.stats.bytes_out) / dt);
    }
    push(charts.latency, "ack p50", ms(st.ack_p50));
    push(charts.latency, "ack p99", ms(st.ack_p99));
    push(charts.latency, "bcast p50", ms(st.broadcast_p50));
    push(charts.latency, "bcast p99", ms(st.broadcast_p99));
    for (const [phase, v] of Object.entries(st.tick_phases)) push(charts.phases, phase, ms(v));
    push(charts.commit, "p50", ms(st.commit_p50));
    push(charts.commit, "p99", ms(st.commit_p99));
    prev = s;
    for (const c of Object.values(charts)) draw(c);
  }

  function start() {
    charts.players = chart("c-players");
    charts.edits = chart("c-edits");
    charts.latency = chart("c-latency");
    charts.phases = chart("c-phases");
    charts.commit = chart("c-commit");
    charts.bytes = chart("c-bytes");
  }

  return { start, onSample };
})();
