// TMOC dashboard: plain JavaScript, no build step, no library. Charts are drawn as SVG here.
// Data comes from the /v1 API with the session cookie (same origin); text goes in via
// textContent only, never as HTML.
"use strict";

const TERMINAL = ["succeeded", "failed", "cancelled"];
const SVGNS = "http://www.w3.org/2000/svg";
let cleanup = [];                     // timers and streams of the page on screen

class AuthError extends Error {}

async function api(path, options = {}) {
  const r = await fetch(path, { credentials: "same-origin", ...options });
  if (r.status === 401) throw new AuthError("401");
  const body = (r.headers.get("content-type") || "").startsWith("application/json") ? await r.json() : null;
  if (!r.ok) throw new Error((body && (body.message || JSON.stringify(body.detail))) || r.statusText);
  return body;
}

function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "text") node.textContent = v; else node.setAttribute(k, v);
  }
  for (const c of children) node.append(c);
  return node;
}

function svg(tag, attrs = {}, text) {
  const node = document.createElementNS(SVGNS, tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  if (text !== undefined) node.textContent = text;
  return node;
}

function fmt(v, digits = 2) {
  return v === null || v === undefined || Number.isNaN(v) ? "–" : Number(v).toFixed(digits);
}

function show(templateId) {
  const main = document.getElementById("main");
  main.replaceChildren(document.getElementById(templateId).content.cloneNode(true));
  return main;
}

function every(ms, fn) {
  const id = setInterval(fn, ms);
  cleanup.push(() => clearInterval(id));
}

// ------------------------------------------------------------------ charts
function scale(d0, d1, r0, r1) {
  const span = d1 - d0 || 1;
  return (v) => r0 + ((v - d0) / span) * (r1 - r0);
}

function axes(root, W, H, m, x, y, xs, ys, labels) {
  root.append(svg("line", { class: "axis", x1: m.l, y1: H - m.b, x2: W - m.r, y2: H - m.b }));
  root.append(svg("line", { class: "axis", x1: m.l, y1: m.t, x2: m.l, y2: H - m.b }));
  for (const v of xs) root.append(svg("text", { x: x(v), y: H - m.b + 12, "text-anchor": "middle" }, labels.x(v)));
  for (const v of ys) root.append(svg("text", { x: m.l - 4, y: y(v) + 3, "text-anchor": "end" }, labels.y(v)));
}

function ticks(lo, hi, n = 4) {
  if (hi === lo) return [lo];
  return Array.from({ length: n + 1 }, (_, i) => lo + ((hi - lo) * i) / n);
}

// A line chart of points {x, y, lo?, hi?}; `truth` draws a dashed level.
function lineChart(id, title, points, { truth = null, unit = "", digits = 1 } = {}) {
  const W = 420, H = 200, m = { l: 48, r: 10, t: 18, b: 28 };
  const root = svg("svg", { viewBox: `0 0 ${W} ${H}`, width: W, height: H, id, "data-points": points.length });
  root.append(svg("text", { class: "title", x: m.l, y: 12 }, title));
  if (points.length) {
    const xsv = points.map((p) => p.x);
    const ysv = points.flatMap((p) => [p.y, p.lo ?? p.y, p.hi ?? p.y]).concat(truth === null ? [] : [truth]);
    let [y0, y1] = [Math.min(...ysv), Math.max(...ysv)];
    if (y0 === y1) { y0 -= 1; y1 += 1; }
    const pad = (y1 - y0) * 0.1;
    const x = scale(Math.min(...xsv), Math.max(...xsv) === Math.min(...xsv) ? Math.min(...xsv) + 1 : Math.max(...xsv), m.l + 8, W - m.r - 8);
    const y = scale(y0 - pad, y1 + pad, H - m.b, m.t);
    axes(root, W, H, m, x, y, [...new Set(xsv)], ticks(y0 - pad, y1 + pad),
      { x: (v) => String(v), y: (v) => fmt(v, digits) + unit });
    if (points.some((p) => p.lo !== undefined)) {
      const up = points.map((p) => `${x(p.x)},${y(p.hi)}`), down = points.slice().reverse().map((p) => `${x(p.x)},${y(p.lo)}`);
      root.append(svg("polygon", { class: "band", points: up.concat(down).join(" ") }));
    }
    if (truth !== null) root.append(svg("line", { class: "truth", x1: m.l, x2: W - m.r, y1: y(truth), y2: y(truth) }));
    root.append(svg("polyline", { class: "line", points: points.map((p) => `${x(p.x)},${y(p.y)}`).join(" ") }));
    for (const p of points) {
      const c = svg("circle", { class: "point", cx: x(p.x), cy: y(p.y), r: 3.5, "data-episode": p.x, "data-value": p.y });
      c.append(svg("title", {}, `episode ${p.x}: ${fmt(p.y, digits)}${unit}`));
      root.append(c);
    }
  } else {
    root.append(svg("text", { x: W / 2, y: H / 2, "text-anchor": "middle" }, "no episode yet"));
  }
  return root;
}

// A weighted histogram over [edges[0], edges[-1]], the uniform prior's level dashed.
function histogram(name, edges, weights, { mult = 1, unit = "", truth = null, digits = 1 } = {}) {
  const W = 420, H = 170, m = { l: 40, r: 10, t: 18, b: 28 };
  const root = svg("svg", { viewBox: `0 0 ${W} ${H}`, width: W, height: H, class: "histogram",
    "data-property": name, "data-weights": weights.map((w) => w.toFixed(4)).join(",") });
  root.append(svg("text", { class: "title", x: m.l, y: 12 }, name));
  const prior = 1 / weights.length;
  const top = Math.max(prior * 1.5, ...weights);
  const x = scale(edges[0] * mult, edges[edges.length - 1] * mult, m.l, W - m.r);
  const y = scale(0, top, H - m.b, m.t);
  axes(root, W, H, m, x, y, ticks(edges[0] * mult, edges[edges.length - 1] * mult), [0, top],
    { x: (v) => fmt(v, digits), y: (v) => fmt(v, 2) });
  weights.forEach((w, i) => {
    const x0 = x(edges[i] * mult), x1 = x(edges[i + 1] * mult);
    const r = svg("rect", { class: "bar", x: x0 + 0.5, width: Math.max(0.5, x1 - x0 - 1), y: y(w), height: y(0) - y(w), "data-weight": w });
    r.append(svg("title", {}, `${fmt(edges[i] * mult, digits)}–${fmt(edges[i + 1] * mult, digits)}${unit}: ${fmt(w, 3)}`));
    root.append(r);
  });
  root.append(svg("line", { class: "prior", x1: m.l, x2: W - m.r, y1: y(prior), y2: y(prior) }));
  root.append(svg("text", { x: W - m.r, y: y(prior) - 3, "text-anchor": "end" }, "prior"));
  if (truth !== null && truth !== undefined) {
    root.append(svg("line", { class: "truth", x1: x(truth * mult), x2: x(truth * mult), y1: m.t, y2: H - m.b }));
  }
  return root;
}

// ------------------------------------------------------------------ shared panels
function curveCharts(points, trueSize) {
  const util = points.map((p) => ({ x: p.episode, y: p.utility }));
  const size = points.map((p) => ({ x: p.episode, y: p.size_mean * 1000,
    lo: (p.size_mean - p.size_std) * 1000, hi: (p.size_mean + p.size_std) * 1000 }));
  const wrap = el("div", { class: "charts" });
  wrap.append(lineChart("curve-utility", "utility per episode", util, { digits: 0 }));
  wrap.append(lineChart("curve-size", "posterior block size (mm): mean ± std, truth dashed", size,
    { truth: trueSize ? trueSize * 1000 : null, unit: "", digits: 1 }));
  return wrap;
}

function beliefPanel(view, truth = {}) {
  const wrap = el("div");
  const b = view.belief;
  if (!b) {
    wrap.append(el("p", { class: "muted", text: view.learns_belief ? "no belief yet" : `${view.agent} keeps L at the prior` }));
    return wrap;
  }
  const props = view.posterior.properties || { size: { unit: "m" } };
  const names = Object.keys(props);
  const perName = b.histogram.length / names.length;
  b.histogram.forEach((h, d) => {
    const name = names[Math.floor(d / perName)] || `dim ${d}`;
    const isSize = name === "size";
    const label = (perName > 1 ? `${name} [${d % perName}]` : name) +
      `: ${fmt(b.mean[d] * (isSize ? 1000 : 1), isSize ? 2 : 1)} ± ${fmt(b.std[d] * (isSize ? 1000 : 1), isSize ? 2 : 1)}` +
      (isSize ? " mm" : ` ${props[name].unit || ""}`) + `  (ESS ${fmt(b.ess, 1)} of ${b.n})` +
      // issue 24: a property the channels cannot identify is said to be so, not shown as known
      (props[name] && props[name].identified === false ? "  — not identified: the measurements do not pin it down" : "");
    wrap.append(histogram(label, h.edges, h.weights, { mult: isSize ? 1000 : 1, unit: isSize ? " mm" : "",
      truth: isSize ? truth.size ?? null : truth[name] ?? null, digits: isSize ? 0 : 0 }));
  });
  return wrap;
}

// ------------------------------------------------------------------ pages
async function listPage() {
  const main = show("list-template");
  const form = main.querySelector("#new-task");
  try {
    const domains = await api("/v1/domains");
    const select = form.querySelector("select[name=domain]");
    for (const d of domains.items) select.append(el("option", { value: d.name, text: d.name }));
  } catch (e) { if (e instanceof AuthError) return signIn(); }
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const f = new FormData(form);
    const spec = { domain: f.get("domain"), agent: f.get("agent"), particles: +f.get("particles"),
      episodes: +f.get("episodes"), n_blocks: +f.get("n_blocks"), true_size: +f.get("true_size"), seed: +f.get("seed") };
    try {
      const made = await api("/v1/tasks", { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(spec) });
      location.hash = `#/tasks/${made.id}`;
    } catch (e) {
      main.querySelector("#submit-error").textContent = e.message;
    }
  });
  const refresh = async () => {
    const [tasks, sessions] = await Promise.all([api("/v1/tasks?limit=50"), api("/v1/sessions?limit=50")]);
    main.querySelector("#tasks tbody").replaceChildren(...tasks.items.map((t) => el("tr", {},
      el("td", {}, el("a", { href: `#/tasks/${t.id}`, text: t.id })),
      el("td", {}, el("span", { class: `badge ${t.status}`, text: t.status })),
      el("td", {}, el("progress", { max: t.progress.episodes, value: t.progress.episodes_done }),
        ` ${t.progress.episodes_done}/${t.progress.episodes}`),
      el("td", { text: t.spec.agent }), el("td", { text: t.spec.domain || "container" }),
      el("td", { text: t.spec.particles }), el("td", { text: t.latest ? fmt(t.latest.utility, 0) : "–" }),
      el("td", { text: new Date(t.created_at).toLocaleString() }))));
    main.querySelector("#sessions tbody").replaceChildren(...sessions.items.map((s) => el("tr", {},
      el("td", {}, el("a", { href: `#/sessions/${s.id}`, text: s.id })),
      el("td", {}, el("span", { class: `badge ${s.status}`, text: s.status })),
      el("td", { text: `${s.episodes_done}/${s.episodes}` }), el("td", { text: s.step }),
      el("td", { class: "atoms", text: s.pending ? s.pending.action : "–" }),
      el("td", { text: new Date(s.created_at).toLocaleString() }))));
  };
  await guarded(refresh)();
  every(3000, guarded(refresh));
}

async function taskPage(id) {
  const main = show("task-template");
  main.querySelector("#task-id").textContent = id;
  const points = [];
  let task = null;

  const renderTask = (t) => {
    task = t;
    const status = main.querySelector("#status");
    status.textContent = t.status; status.className = `badge ${t.status}`;
    const bar = main.querySelector("#progress-bar");
    bar.max = t.progress.episodes; bar.value = t.progress.episodes_done;
    main.querySelector("#progress").textContent = `${t.progress.episodes_done}/${t.progress.episodes} episodes` +
      (t.error ? ` — ${t.error}` : "");
    const s = t.spec;
    main.querySelector("#spec").textContent = ` ${s.domain || "container"}, ${s.agent}, ${s.particles} particles, ` +
      `${s.n_blocks} blocks, seed ${s.seed}`;
    const latest = t.latest;
    const plan = main.querySelector("#plan");
    if (latest) {
      plan.replaceChildren(
        el("p", { text: `episode ${latest.episode}: utility ${fmt(latest.utility, 0)}, ${latest.actions} actions, ` +
          `delivered ${latest.delivered}, failures ${JSON.stringify(latest.failures)}` }),
        el("p", { class: "atoms", id: "loads", text: `loads per trip: ${JSON.stringify(latest.loads)}` }),
        el("p", { class: "atoms", text: `plans (loads per trip, one per replan): ${JSON.stringify(latest.plans)}` }));
    } else {
      plan.replaceChildren(el("p", { class: "muted", text: "no episode yet" }));
    }
    main.querySelector("#nodes tbody").replaceChildren(...(t.nodes || []).map((n) => el("tr", {},
      el("td", { class: "atoms", text: n.node_id.slice(0, 12) }), el("td", { text: n.hostname }),
      el("td", { text: n.shards }), el("td", { text: n.particle_actions }))));
  };

  const drawCurve = () => main.querySelector("#curve").replaceChildren(curveCharts(points, task && task.spec.true_size));
  const drawBelief = async () => {
    const view = await api(`/v1/tasks/${id}/belief`);
    const truth = { size: view.true_size, ...((task && task.spec.truth) || {}) };
    main.querySelector("#belief").replaceChildren(beliefPanel(view, truth));
  };
  const drawT = async () => {
    const t = await api(`/v1/tasks/${id}/transition`);
    main.querySelector("#transition").setAttribute("data-episodes", t.episodes_done);
    main.querySelector("#transition tbody").replaceChildren(...t.rows.map((r) => el("tr", { "data-p": r.p.toFixed(4) },
      el("td", { text: r.action }), el("td", { text: r.context }),
      el("td", {}, el("span", { class: "pbar", "data-w": r.p }), fmt(r.p, 3)),
      el("td", { text: `${fmt(r.successes, 2)} / ${fmt(r.trials, 2)}` }),
      el("td", { text: `${fmt(r.real_successes, 0)} / ${fmt(r.real_trials, 0)}` }))));
    for (const s of main.querySelectorAll("#transition .pbar")) s.style.width = `${Math.round(60 * +s.dataset.w)}px`;
  };
  const drawFrames = async () => {
    const list = await api(`/v1/tasks/${id}/frames`);
    const box = main.querySelector("#frames");
    if (box.getAttribute("data-names") === list.items.map((f) => f.name).join(",")) return;
    box.setAttribute("data-names", list.items.map((f) => f.name).join(","));
    box.replaceChildren(...list.items.slice().reverse().map((f) => el("figure", { "data-name": f.name },
      el("img", { src: f.url, alt: f.panels.map((p) => p.title).join(" | "), loading: "lazy" }),
      el("figcaption", { text: f.kind === "episode_end" ? `episode ${f.episode}: the real world at its end`
        : `episode ${f.episode}, action ${f.step}: ${f.action} failed — real vs. particles' predictions` }))));
    if (!list.items.length) box.append(el("p", { class: "muted", text: "no picture yet" }));
  };
  const refreshAll = async () => {
    renderTask(await api(`/v1/tasks/${id}`));
    await Promise.all([drawBelief(), drawT(), drawFrames()]);
  };

  try {
    renderTask(await api(`/v1/tasks/${id}`));
  } catch (e) {
    if (e instanceof AuthError) return signIn();
    main.replaceChildren(el("p", { class: "error", text: e.message }));
    return;
  }
  drawCurve();
  await guarded(refreshAll)();

  // Live: one `episode` event per finished episode (resumed with Last-Event-ID by the
  // browser), `status` events; closed at the final status (else EventSource reconnects).
  const source = new EventSource(`/v1/tasks/${id}/events`);
  cleanup.push(() => source.close());
  source.addEventListener("episode", (ev) => {
    const r = JSON.parse(ev.data);
    if (points.some((p) => p.episode === r.episode)) return;
    points.push({ episode: r.episode, utility: r.utility, size_mean: r.posterior.size_mean, size_std: r.posterior.size_std });
    points.sort((a, b) => a.episode - b.episode);
    // The point once the belief and T of its episode are drawn: the page never shows an
    // episode beside the belief from before it (a slow fetch did, on a loaded machine).
    guarded(async () => { try { await refreshAll(); } finally { drawCurve(); } })();
  });
  source.addEventListener("status", (ev) => {
    const t = JSON.parse(ev.data);
    renderTask(t);
    if (TERMINAL.includes(t.status)) { source.close(); guarded(refreshAll)(); }
  });
  // Failed actions' pictures arrive mid-episode: look for them while the task runs.
  every(3000, guarded(async () => { if (task && !TERMINAL.includes(task.status)) await drawFrames(); }));
}

async function sessionPage(id) {
  const main = show("session-template");
  main.querySelector("#session-id").textContent = id;
  const refresh = async () => {
    const s = await api(`/v1/sessions/${id}`);
    const status = main.querySelector("#status");
    status.textContent = s.status; status.className = `badge ${s.status}`;
    main.querySelector("#session-progress").textContent =
      `${s.episodes_done}/${s.episodes} episodes done; ${s.in_episode ? `in episode, step ${s.step}` : "between episodes"}`;
    const p = s.pending;
    main.querySelector("#pending").replaceChildren(p
      ? el("div", {}, el("p", { class: "atoms", id: "pending-action", text: p.action }),
        el("p", { class: "muted", text: `episode ${p.episode}, step ${p.step}; key pose ${p.pose.map((v) => fmt(v, 3)).join(", ")}` }))
      : el("p", { class: "muted", text: "no pending action" }));
    main.querySelector("#expected").replaceChildren(...(p ? p.expected : []).map((a) => el("li", { class: "atoms", text: a })));
    const traj = main.querySelector("#trajectory");
    if (p && p.trajectory.length) {
      const cols = p.trajectory_columns;
      const series = (name) => p.trajectory.map((row) => ({ x: row[0], y: row[cols.indexOf(name)] }));
      traj.replaceChildren(lineChart("traj-x", "x (m) over t (s)", series("x"), { digits: 2 }),
        lineChart("traj-z", "z (m) over t (s)", series("z"), { digits: 2 }),
        el("p", { class: "muted", text: `${p.trajectory.length} rows: ${cols.join(", ")}` }));
    } else traj.replaceChildren(el("p", { class: "muted", text: "–" }));
    const o = s.last_observation;
    main.querySelector("#observation").replaceChildren(o
      ? el("div", {}, el("p", { class: "atoms", text: `${o.action}: ${o.success ? "succeeded" : "failed"}` }),
        el("p", { class: "atoms", text: `robot ${o.configuration.robot.map((v) => fmt(v, 3)).join(", ")}` }),
        el("ul", {}, ...o.state.map((a) => el("li", { class: "atoms", text: a }))))
      : el("p", { class: "muted", text: "no observation yet" }));
    const [belief, curve] = await Promise.all([api(`/v1/sessions/${id}/belief`), api(`/v1/sessions/${id}/curve`)]);
    main.querySelector("#belief").replaceChildren(beliefPanel(belief));
    main.querySelector("#curve").replaceChildren(curveCharts(curve.points, null));
  };
  await guarded(refresh)();
  every(2000, guarded(refresh));
}

function signIn() {
  for (const f of cleanup.splice(0)) f();
  show("signin-template");
  document.getElementById("token").focus();
}

// Any call may find the session gone (expired, or the server restarted): sign in again.
function guarded(fn) {
  return async (...args) => {
    try { return await fn(...args); } catch (e) {
      if (e instanceof AuthError) signIn(); else console.warn(e);
    }
  };
}

async function route() {
  for (const f of cleanup.splice(0)) f();
  const hash = location.hash || "#/";
  let m;
  if ((m = hash.match(/^#\/tasks\/([\w-]+)$/))) return taskPage(m[1]);
  if ((m = hash.match(/^#\/sessions\/([\w-]+)$/))) return sessionPage(m[1]);
  return listPage();
}

async function start() {
  try {
    const health = await api("/health");
    document.getElementById("logout").hidden = !health.auth;
  } catch (e) { /* degraded servers answer 503: the pages say more */ }
  window.addEventListener("hashchange", route);
  route();
}

start();
