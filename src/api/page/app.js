// The operator's page of `csmetro serve`. Everything comes from the JSON routes; the token, when
// the service needs one, is sent in the Authorization header (never in a URL), which is why
// the event stream is read with fetch() rather than EventSource, and result files and plots
// are fetched before they are shown.
'use strict';

const LIST_EVERY_MS = 2000; // refresh of the campaign list (and the selected one's status)
const SAMPLES_PAGE = 10000; // the API's largest page of samples
const LIVE = ['queued', 'running', 'paused'];

const S = {
  token: sessionStorage.getItem('csmetro-token') || '',
  list: [],
  sel: null, // the campaign shown in detail
  listTimer: null,
  // For the browser test and the latency target: measured on this page, in this browser.
  stats: { listPaintMs: null, samplesDrawn: 0, liveSamples: 0, maxLatencyS: 0, sumLatencyS: 0 },
};
window.csmetroStats = S.stats;

const $ = (id) => document.getElementById(id);

function el(tag, attrs, ...kids) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (k === 'class') e.className = v;
    else if (k.startsWith('on')) e.addEventListener(k.slice(2), v);
    else if (v !== null && v !== undefined) e.setAttribute(k, v);
  }
  for (const k of kids) e.append(k instanceof Node ? k : document.createTextNode(String(k)));
  return e;
}

function hms(s) {
  if (s === null || s === undefined || !isFinite(s) || s < 0) return '–';
  const t = Math.round(s);
  const h = Math.floor(t / 3600), m = Math.floor(t / 60) % 60, x = t % 60;
  return `${h}:${String(m).padStart(2, '0')}:${String(x).padStart(2, '0')}`;
}

function when(unix) {
  if (!unix) return '';
  return new Date(unix * 1000).toLocaleString();
}

function fmt(v, digits) {
  return (v === null || v === undefined || !isFinite(v)) ? '–' : Number(v).toFixed(digits ?? 3);
}

function notice(msg) {
  const n = $('notice');
  n.textContent = msg || '';
  n.hidden = !msg;
}

class AuthNeeded extends Error {}

function headers(extra) {
  const h = Object.assign({}, extra || {});
  if (S.token) h['Authorization'] = 'Bearer ' + S.token;
  return h;
}

// fetch() with the token; a 401 asks for it.
async function api(path, opts) {
  const o = Object.assign({}, opts || {});
  o.headers = headers(o.headers);
  const r = await fetch(path, o);
  if (r.status === 401) {
    askToken(S.token ? 'The token was refused.' : '');
    throw new AuthNeeded('token needed');
  }
  return r;
}

// The service's `{"error": ...}` text of a failed reply.
async function errorOf(r) {
  try {
    const j = await r.json();
    if (j && typeof j.error === 'string') return j.error;
  } catch (_) { /* not JSON */ }
  return `HTTP ${r.status}`;
}

async function getJson(path) {
  const r = await api(path);
  if (!r.ok) throw new Error(await errorOf(r));
  return r.json();
}

function askToken(msg) {
  $('token-form').hidden = false;
  notice(msg || 'This service needs a token.');
  $('token').focus();
}

$('token-form').addEventListener('submit', (ev) => {
  ev.preventDefault();
  S.token = $('token').value.trim();
  sessionStorage.setItem('csmetro-token', S.token);
  $('token-form').hidden = true;
  notice('');
  start();
});

// ---------------------------------------------------------------- campaign list

async function refreshList() {
  try {
    const [health, list] = await Promise.all([getJson('/health'), getJson('/campaigns')]);
    $('service').textContent = `service ${health.status}, version ${health.version}`;
    S.list = list;
    renderList();
    if (S.stats.listPaintMs === null) {
      // The list is in the DOM: the next frame paints it.
      requestAnimationFrame(() => {
        S.stats.listPaintMs = performance.now();
        performance.mark('csmetro-list-painted');
      });
    }
    if (S.sel) {
      const st = list.find((c) => c.id === S.sel.id);
      if (st) showStatus(st);
    }
    notice('');
  } catch (e) {
    if (e instanceof AuthNeeded) return;
    notice(`Cannot reach the service: ${e.message}`);
  }
}

function renderList() {
  const body = $('campaigns').tBodies[0];
  const rows = S.list.map((c) => {
    const tr = el('tr', { 'data-id': c.id, 'data-state': c.state, onclick: () => select(c.id) },
      el('td', { class: 'num' }, c.id),
      el('td', {}, c.name),
      el('td', {}, c.stage),
      el('td', { class: 'state-' + c.state }, c.state +
        (c.queue_position !== null && c.queue_position !== undefined ? ` (#${c.queue_position})` : '')),
      el('td', {}, progressCell(c.percent)),
      el('td', { class: 'num' }, `${c.stored} / ${c.planned}`),
      el('td', { class: 'num' }, hms(c.elapsed_s)),
      el('td', { class: 'num eta' }, hms(c.eta_s)),
      el('td', {}, when(c.updated_unix_s)));
    if (S.sel && S.sel.id === c.id) tr.classList.add('selected');
    return tr;
  });
  body.replaceChildren(...rows);
  $('empty').hidden = S.list.length > 0;
}

// Inline style attributes are barred by the page's CSP: the width goes through the CSSOM.
function progressCell(pct) {
  const p = Math.max(0, Math.min(100, pct || 0));
  const fill = el('span');
  fill.style.width = `${p}%`;
  return el('span', { class: 'progress' }, el('span', { class: 'bar' }, fill), ` ${p.toFixed(1)} %`);
}

// ---------------------------------------------------------------- one campaign

function select(id) {
  if (S.sel && S.sel.id === id) return;
  if (S.sel) S.sel.abort.abort();
  history.replaceState(null, '', '#' + id);
  S.sel = {
    id,
    abort: new AbortController(),
    samples: new Map(), // seq -> sample record
    curves: new Map(), // component -> Map(run label -> [[pos, err]])
    charts: new Map(), // component -> canvas
    results: [],
    resultsKey: '',
    isoKey: '',
    lastEvent: 0,
    drawPending: false,
    live: true,
    state: null,
    // A `[map]` campaign: samples per approach direction ([x, y, ex, ey]), the reconstructed
    // grids (map_<dir>.csv), the figures drawn.
    map: { samples: new Map(), grids: new Map(), figs: new Map(), loading: new Set(), dirty: false, isoDone: false },
  };
  $('detail').hidden = false;
  $('plots').replaceChildren();
  $('lines').hidden = false;
  $('maps').hidden = true;
  $('map-body').replaceChildren();
  $('map-count').textContent = '';
  $('iso2301').hidden = true;
  $('iso2301-body').replaceChildren();
  $('verification').hidden = true;
  $('verification-body').replaceChildren();
  $('events').replaceChildren();
  $('results').replaceChildren(el('li', { class: 'note' }, 'none yet'));
  $('iso').hidden = true;
  $('iso-body').replaceChildren();
  $('report-link').hidden = true;
  $('control-msg').textContent = '';
  $('plot-count').textContent = '';
  renderList();
  const st = S.list.find((c) => c.id === id);
  if (st) showStatus(st);
  const sel = S.sel;
  streamEvents(sel);
  loadSamples(sel);
  loadResults(sel);
}

function showStatus(st) {
  const sel = S.sel;
  // What a button did is old news once the state moves on.
  if (sel.state !== null && sel.state !== st.state) $('control-msg').textContent = '';
  sel.state = st.state;
  sel.live = LIVE.includes(st.state);
  // Fewer samples drawn than were stored a refresh ago: live events were missed (a slow
  // client, a reconnection); the store has them all.
  if (sel.prevStored !== undefined && sel.samples.size < sel.prevStored) loadSamples(sel);
  sel.prevStored = st.stored;
  $('detail-title').textContent = `Campaign ${st.id} “${st.name}” on ${st.stage}`;
  const parts = [`${st.state}`, `${st.stored} / ${st.planned} samples (${Number(st.percent).toFixed(1)} %)`];
  if (st.elapsed_s !== null && st.elapsed_s !== undefined) parts.push(`elapsed ${hms(st.elapsed_s)}`);
  if (st.eta_s !== null && st.eta_s !== undefined) parts.push(`ETA ${hms(st.eta_s)}`);
  if (st.queue_position !== null && st.queue_position !== undefined) parts.push(`queue position ${st.queue_position}`);
  if (st.message) parts.push(st.message);
  const p = $('detail-state');
  p.replaceChildren(progressCell(st.percent), ' ', parts.join(' · '));
  p.dataset.state = st.state;
  p.dataset.stored = st.stored;
  $('btn-pause').disabled = st.state !== 'running';
  $('btn-resume').disabled = !['paused', 'interrupted'].includes(st.state);
  $('btn-abort').disabled = !['queued', 'running', 'paused', 'interrupted'].includes(st.state);
}

async function control(action) {
  const sel = S.sel;
  if (!sel) return;
  if (action === 'abort' &&
      !confirm(`Abort campaign ${sel.id}? Motion stops and the campaign cannot be resumed.`)) return;
  $('control-msg').textContent = `${action}…`;
  try {
    // JSON, as the service asks of every browser request that changes something.
    const r = await api(`/campaigns/${sel.id}/${action}`, {
      method: 'POST',
      headers: { 'Content-Type': 'application/json' },
      body: '{}',
    });
    if (!r.ok) {
      $('control-msg').textContent = await errorOf(r);
      return;
    }
    const st = await r.json();
    if (S.sel === sel) showStatus(st);
    $('control-msg').textContent = `${action}: ${st.state}`;
    // A resumed (interrupted) campaign streams again.
    if (action === 'resume' && !sel.streaming) streamEvents(sel);
    refreshList();
  } catch (e) {
    if (!(e instanceof AuthNeeded)) $('control-msg').textContent = e.message;
  }
}

$('btn-pause').addEventListener('click', () => control('pause'));
$('btn-resume').addEventListener('click', () => control('resume'));
$('btn-abort').addEventListener('click', () => control('abort'));

// Server-sent events over fetch(): the stored log, then live events until `finished`.
async function streamEvents(sel) {
  sel.streaming = true;
  try {
    while (S.sel === sel) {
      let r;
      try {
        r = await api(`/campaigns/${sel.id}/events?after=${sel.lastEvent}`,
          { headers: { Accept: 'text/event-stream' }, signal: sel.abort.signal });
      } catch (e) {
        if (e instanceof AuthNeeded || sel.abort.signal.aborted) return;
        await sleep(1000);
        continue;
      }
      if (!r.ok) {
        notice(await errorOf(r));
        return;
      }
      let ended = false;
      try {
        ended = await readSse(r.body, (ev) => onEvent(sel, ev));
      } catch (_) {
        if (sel.abort.signal.aborted) return;
      }
      if (ended) return;
      // The stream ended without `finished`: the service restarted or the campaign rests
      // (interrupted, waiting for an operator). Follow again while it is live.
      await sleep(1000);
      if (!sel.live) return;
    }
  } finally {
    sel.streaming = false;
  }
}

function sleep(ms) {
  return new Promise((res) => setTimeout(res, ms));
}

// Reads an SSE body, calling `each({event, id, data})`; true when a `finished` event came.
async function readSse(body, each) {
  const reader = body.getReader();
  const dec = new TextDecoder();
  let buf = '';
  let finished = false;
  for (;;) {
    const { value, done } = await reader.read();
    if (done) break;
    buf += dec.decode(value, { stream: true }).replace(/\r\n?/g, '\n');
    let cut;
    while ((cut = buf.indexOf('\n\n')) >= 0) {
      const block = buf.slice(0, cut);
      buf = buf.slice(cut + 2);
      const ev = { event: 'message', id: null, data: '' };
      const data = [];
      for (const line of block.split('\n')) {
        if (!line || line.startsWith(':')) continue;
        const i = line.indexOf(':');
        const f = i < 0 ? line : line.slice(0, i);
        let v = i < 0 ? '' : line.slice(i + 1);
        if (v.startsWith(' ')) v = v.slice(1);
        if (f === 'event') ev.event = v;
        else if (f === 'id') ev.id = Number(v);
        else if (f === 'data') data.push(v);
      }
      if (!data.length) continue;
      ev.data = data.join('\n');
      each(ev);
      if (ev.event === 'finished') finished = true;
    }
  }
  return finished;
}

function onEvent(sel, ev) {
  if (S.sel !== sel) return;
  let e;
  try { e = JSON.parse(ev.data); } catch (_) { return; }
  if (ev.id) sel.lastEvent = Math.max(sel.lastEvent, ev.id);
  if (ev.event === 'sample') {
    const fresh = addSample(sel, e.data);
    if (fresh) {
      S.stats.liveSamples += 1;
      sel.pendingLatency = sel.pendingLatency || [];
      sel.pendingLatency.push(e.data.unix_s);
    }
    return;
  }
  logEvent(e);
  if (ev.event === 'reconstructed' && e.data && e.data.run && e.data.component) {
    loadCurve(sel, e.data.run, e.data.component);
  }
  if (ev.event === 'finished') {
    sel.live = false;
    // The last samples, had any live event been missed; then the results and the ISO figures.
    loadSamples(sel);
    loadResults(sel);
    refreshList();
  }
}

function logEvent(e) {
  const d = e.data && typeof e.data === 'object' ? e.data : {};
  let text;
  if (e.kind === 'finished' && d.summary) {
    const t = d.summary.total || {};
    text = `finished ${d.state}: ${d.summary.samples} samples` +
      (t.acquisition_saved_pct !== null && t.acquisition_saved_pct !== undefined
        ? `, acquisition saved ${fmt(t.acquisition_saved_pct, 2)} %` : '') +
      (d.errors && d.errors.length ? `; errors: ${d.errors.join('; ')}` : '');
  } else {
    const s = JSON.stringify(d);
    text = `${e.kind} ${s.length > 300 ? s.slice(0, 300) + '…' : s}`;
  }
  const li = el('li', { 'data-kind': e.kind }, `${new Date(e.unix_s * 1000).toLocaleTimeString()}  ${text}`);
  const list = $('events');
  list.prepend(li);
  while (list.children.length > 500) list.lastChild.remove();
}

// Committed samples (those a live stream missed too), page by page.
async function loadSamples(sel) {
  if (sel.loadingSamples) return;
  sel.loadingSamples = true;
  let after = sel.samplesAfter || 0;
  try {
    for (;;) {
      const page = await getJson(`/campaigns/${sel.id}/samples?after=${after}&limit=${SAMPLES_PAGE}`);
      if (S.sel !== sel) return;
      for (const it of page.samples) addSample(sel, it.sample);
      if (!page.samples.length || page.next <= after) break;
      after = page.next;
      sel.samplesAfter = after;
    }
  } catch (e) {
    if (!(e instanceof AuthNeeded)) notice(`Samples: ${e.message}`);
  } finally {
    sel.loadingSamples = false;
  }
}

function runLabel(run) {
  return `${run.phase}-${run.axis}-${run.direction}-${run.cycle}`;
}

// Adds one sample to the plots of the two components its run measures; false if known.
function addSample(sel, s) {
  if (!s || !s.target || sel.samples.has(s.target.seq)) return false;
  sel.samples.set(s.target.seq, s);
  const run = s.target.run;
  if (run.phase === 'map') {
    // Both axes move: an error against one axis's position means nothing; drawn over XY.
    addMapSample(sel, s);
    scheduleDraw(sel);
    return true;
  }
  const other = run.axis === 'x' ? 'y' : 'x';
  const d = run.direction === 'backward' ? 'b' : 'f';
  const pos = run.axis === 'x' ? s.target.target_x_um : s.target.target_y_um;
  for (const m of [run.axis, other]) {
    const err = m === 'x' ? s.meas_x_um - s.target.target_x_um : s.meas_y_um - s.target.target_y_um;
    const comp = `e${d}_${run.axis}${m}`;
    const c = chart(sel, comp);
    c.points.push([pos, err, run.phase === 'full']);
    c.dirty = true;
  }
  scheduleDraw(sel);
  return true;
}

// The chart of one component, made on first use, kept in name order.
function chart(sel, comp) {
  let c = sel.charts.get(comp);
  if (c) return c;
  const canvas = el('canvas', { width: 520, height: 300, 'data-component': comp, 'data-points': 0, 'data-curves': 0 });
  const fig = el('figure', { 'data-component': comp }, el('figcaption', {}, comp), canvas);
  c = { comp, canvas, fig, points: [], curves: new Map() };
  sel.charts.set(comp, c);
  $('lines').hidden = false;
  const figs = [...sel.charts.values()].sort((a, b) => a.comp.localeCompare(b.comp)).map((x) => x.fig);
  $('plots').replaceChildren(...figs);
  return c;
}

function scheduleDraw(sel) {
  if (sel.drawPending) return;
  sel.drawPending = true;
  requestAnimationFrame(() => {
    sel.drawPending = false;
    if (S.sel !== sel) return;
    // Only the charts that changed: each sample touches two of them.
    for (const c of sel.charts.values()) {
      if (c.dirty) { c.dirty = false; draw(c); }
    }
    if (sel.map.dirty) { sel.map.dirty = false; drawMaps(sel); }
    $('plot-count').textContent = `${sel.samples.size} samples`;
    $('plots').dataset.samples = sel.samples.size;
    S.stats.samplesDrawn = sel.samples.size;
    // Time from a sample's measurement to its dot on the screen (this frame).
    const now = Date.now() / 1000;
    for (const t of sel.pendingLatency || []) {
      const l = Math.max(0, now - t);
      S.stats.maxLatencyS = Math.max(S.stats.maxLatencyS, l);
      S.stats.sumLatencyS += l;
    }
    sel.pendingLatency = [];
  });
}

const COLORS = ['#0a58ca', '#d63384', '#198754', '#fd7e14', '#6f42c1', '#20c997', '#6c757d'];

function niceTicks(lo, hi, n) {
  const span = hi - lo || 1;
  const step0 = span / n;
  const mag = Math.pow(10, Math.floor(Math.log10(step0)));
  const step = [1, 2, 5, 10].map((k) => k * mag).find((s) => s >= step0) || step0;
  const ticks = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) ticks.push(+v.toPrecision(12));
  return ticks;
}

// One plot: axes with ticks, curves as lines, samples as dots. `extra(ctx, X, Y)` draws more.
function plotFrame(canvas, xs, ys, xlabel, ylabel) {
  const ctx = canvas.getContext('2d');
  const W = canvas.width, H = canvas.height;
  const L = 58, R = 20, T = 10, B = 36;
  ctx.clearRect(0, 0, W, H);
  let [x0, x1] = [Math.min(...xs), Math.max(...xs)];
  let [y0, y1] = [Math.min(...ys), Math.max(...ys)];
  if (!isFinite(x0)) [x0, x1] = [0, 1];
  if (!isFinite(y0)) [y0, y1] = [-1, 1];
  if (x1 - x0 < 1e-9) { x0 -= 1; x1 += 1; }
  const pad = (y1 - y0) * 0.08 || 0.5;
  y0 -= pad; y1 += pad;
  const X = (v) => L + (v - x0) / (x1 - x0) * (W - L - R);
  const Y = (v) => H - B - (v - y0) / (y1 - y0) * (H - T - B);
  ctx.font = '11px system-ui, sans-serif';
  ctx.strokeStyle = '#d0d7de';
  ctx.fillStyle = '#5b6570';
  ctx.lineWidth = 1;
  ctx.textAlign = 'center';
  for (const t of niceTicks(x0, x1, 6)) {
    ctx.beginPath(); ctx.moveTo(X(t), T); ctx.lineTo(X(t), H - B); ctx.stroke();
    ctx.fillText(String(t), X(t), H - B + 14);
  }
  ctx.textAlign = 'right';
  for (const t of niceTicks(y0, y1, 5)) {
    ctx.beginPath(); ctx.moveTo(L, Y(t)); ctx.lineTo(W - R, Y(t)); ctx.stroke();
    ctx.fillText(String(t), L - 4, Y(t) + 4);
  }
  ctx.textAlign = 'center';
  ctx.fillText(xlabel, (L + W - R) / 2, H - 4);
  ctx.save();
  ctx.translate(12, (T + H - B) / 2);
  ctx.rotate(-Math.PI / 2);
  ctx.fillText(ylabel, 0, 0);
  ctx.restore();
  ctx.strokeStyle = '#1b1f24';
  ctx.strokeRect(L, T, W - L - R, H - T - B);
  return { ctx, X, Y, W, H, L, R, T, B };
}

function draw(c) {
  const xs = [], ys = [];
  for (const [x, y] of c.points) { xs.push(x); ys.push(y); }
  for (const pts of c.curves.values()) for (const [x, y] of pts) { xs.push(x); ys.push(y); }
  const f = plotFrame(c.canvas, xs, ys, 'target position (µm)', 'error (µm)');
  const { ctx, X, Y } = f;
  let i = 0;
  const legend = [];
  for (const [label, pts] of [...c.curves.entries()].sort()) {
    const color = COLORS[i++ % COLORS.length];
    ctx.strokeStyle = color;
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    pts.forEach(([x, y], k) => (k ? ctx.lineTo(X(x), Y(y)) : ctx.moveTo(X(x), Y(y))));
    ctx.stroke();
    legend.push([label, color]);
  }
  for (const [x, y, full] of c.points) {
    ctx.beginPath();
    ctx.arc(X(x), Y(y), full ? 2 : 2.5, 0, 2 * Math.PI);
    if (full) { ctx.strokeStyle = '#6c757d'; ctx.lineWidth = 1; ctx.stroke(); }
    else { ctx.fillStyle = '#1b1f24'; ctx.fill(); }
  }
  ctx.textAlign = 'left';
  legend.forEach(([label, color], k) => {
    ctx.fillStyle = color;
    ctx.fillText(`— ${label}`, f.L + 6, f.T + 12 + 12 * k);
  });
  c.canvas.dataset.points = c.points.length;
  c.canvas.dataset.curves = c.curves.size;
}

// The reconstruction of `comp` from run `run` (a result CSV: position_um,error_um).
async function loadCurve(sel, run, comp) {
  try {
    const r = await api(`/campaigns/${sel.id}/results/curves/${encodeURIComponent(run)}-${encodeURIComponent(comp)}.csv`);
    if (!r.ok || S.sel !== sel) return;
    const pts = [];
    for (const line of (await r.text()).split('\n').slice(1)) {
      const [p, v] = line.split(',').map(Number);
      if (isFinite(p) && isFinite(v)) pts.push([p, v]);
    }
    if (!pts.length) return;
    const c = chart(sel, comp);
    c.curves.set(run, pts);
    c.dirty = true;
    scheduleDraw(sel);
  } catch (_) { /* shown at the next event */ }
}

// ---------------------------------------------------------------- results and ISO 230-2

async function loadResults(sel) {
  let names;
  try {
    names = (await getJson(`/campaigns/${sel.id}/results`)).results || [];
  } catch (e) {
    if (!(e instanceof AuthNeeded)) notice(`Results: ${e.message}`);
    return;
  }
  if (S.sel !== sel) return;
  const key = names.join('\n');
  if (key === sel.resultsKey) return;
  sel.resultsKey = key;
  sel.results = names;
  const list = $('results');
  if (!names.length) {
    list.replaceChildren(el('li', { class: 'note' }, 'none yet'));
  } else {
    list.replaceChildren(...names.map((n) => {
      const href = `/campaigns/${sel.id}/results/${n.split('/').map(encodeURIComponent).join('/')}`;
      const a = el('a', { href, 'data-name': n, target: '_blank', rel: 'noopener' }, n);
      a.addEventListener('click', (ev) => openResult(ev, href, n));
      return el('li', {}, a);
    }));
  }
  // Curves stored before the page opened (their events are in the log too; this is cheap).
  for (const n of names) {
    const m = /^curves\/(.+)-(e[fb]_[xy][xy])\.csv$/.exec(n);
    if (m && !(sel.charts.get(m[2]) && sel.charts.get(m[2]).curves.has(m[1]))) loadCurve(sel, m[1], m[2]);
  }
  // The printable report, when the campaign has one, also next to the title.
  const rep = $('report-link');
  if (names.includes('report.html')) {
    const href = `/campaigns/${sel.id}/results/report.html`;
    const a = el('a', { href, target: '_blank', rel: 'noopener' }, 'report.html');
    a.addEventListener('click', (ev) => openResult(ev, href, 'report.html'));
    rep.replaceChildren('Report: ', a);
    rep.hidden = false;
  } else {
    rep.hidden = true;
  }
  showIso(sel, names);
  // A map campaign's reconstructed grids and its ISO 230-1 figures (summary.json `map`).
  const maps = names.map((n) => /^map_(forward|backward)\.csv$/.exec(n)).filter(Boolean);
  for (const m of maps) loadMapGrid(sel, m[1], m[0]);
  if (maps.length && names.includes('summary.json')) showIso2301(sel);
  if (names.includes('verify/verify.json')) showVerification(sel, names);
}

// The last `csmetro verify` of this campaign (GET /campaigns/{id}/verification): the verdict,
// the before/after table per axis and its charts (verify/verify_<axis>.svg, pass line drawn).
async function showVerification(sel, names) {
  const key = names.filter((n) => n.startsWith('verify/')).join('\n');
  if (key === sel.verifyKey) return;
  sel.verifyKey = key;
  let v;
  try {
    v = await getJson(`/campaigns/${sel.id}/verification`);
  } catch (e) {
    if (!(e instanceof AuthNeeded)) notice(`Verification: ${e.message}`);
    return;
  }
  if (S.sel !== sel || !v || typeof v !== 'object') return;
  const kids = [el('p', { class: v.passed ? 'state-done' : 'state-failed', 'data-passed': String(!!v.passed) },
    `Verification ${v.passed ? 'passed' : 'FAILED'}${v.kind === 'map' ? ' (map)' : ''}`)];
  const axes = Array.isArray(v.axes) ? v.axes.filter((a) => a && a.before && a.after) : [];
  if (axes.length) {
    kids.push(el('table', { class: 'verify-table' },
      el('thead', {}, el('tr', {}, ...['axis', 'E before', 'E after', 'mean |e| before', 'mean |e| after',
        'max |after|', 'expected', 'verdict'].map((h, i) => el('th', { class: i ? 'num' : '' }, h)))),
      el('tbody', {}, ...axes.map((a) => el('tr', { 'data-axis': a.axis },
        el('td', {}, String(a.axis)),
        ...[a.before.e_um, a.after.e_um, a.mean_abs_before_um, a.mean_abs_after_um, a.max_abs_after_um,
          a.expected_um].map((x) => el('td', { class: 'num' }, fmt(x))),
        el('td', { class: a.passed ? 'state-done' : 'state-failed' }, a.passed ? 'pass' : 'FAIL'))))));
    kids.push(el('p', { class: 'note' }, 'µm; every compensated approach must stay within ±expected (the pass line on the charts).'));
  }
  for (const n of names.filter((x) => /^verify\/verify_[a-z]+\.svg$/.test(x))) {
    const url = await blobUrl(sel, n);
    if (url) kids.push(el('figure', {}, el('figcaption', {}, n), el('img', { src: url, alt: `verification chart ${n}` })));
  }
  if (S.sel !== sel) return;
  $('verification-body').replaceChildren(...kids);
  $('verification').hidden = false;
}

// With a token a plain link cannot authenticate: fetch the file, then open it.
async function openResult(ev, href, name) {
  if (!S.token) return;
  ev.preventDefault();
  try {
    const r = await api(href);
    if (!r.ok) { notice(`${name}: ${await errorOf(r)}`); return; }
    const url = URL.createObjectURL(await r.blob());
    const a = el('a', { href: url, download: name.split('/').pop() });
    document.body.append(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(url), 60000);
  } catch (e) {
    if (!(e instanceof AuthNeeded)) notice(`${name}: ${e.message}`);
  }
}

async function blobUrl(sel, name) {
  const r = await api(`/campaigns/${sel.id}/results/${name.split('/').map(encodeURIComponent).join('/')}`);
  if (!r.ok) return null;
  return URL.createObjectURL(await r.blob());
}

// The ISO 230-2 figures (`iso230.json`) as a table and a chart per axis, plus any ISO plot the
// campaign stored (`plots/*iso*`). Nothing is shown while the campaign has none.
async function showIso(sel, names) {
  const isoPlots = names.filter((n) => /^plots\/.*iso.*\.(svg|png)$/i.test(n));
  const hasJson = names.includes('iso230.json');
  if (!hasJson && !isoPlots.length) return;
  const key = names.filter((n) => n === 'iso230.json' || isoPlots.includes(n)).join('\n');
  if (key === sel.isoKey) return;
  sel.isoKey = key;
  const body = [];
  if (hasJson) {
    try {
      const iso = await getJson(`/campaigns/${sel.id}/results/iso230.json`);
      for (const [axis, v] of Object.entries(iso || {})) {
        const part = isoAxis(axis, v);
        if (part) body.push(part);
      }
    } catch (e) {
      if (!(e instanceof AuthNeeded)) body.push(el('p', { class: 'note' }, `iso230.json: ${e.message}`));
    }
  }
  // Prefer the SVG of a plot that exists in both forms.
  const shown = isoPlots.filter((n) => !(n.endsWith('.png') && isoPlots.includes(n.replace(/\.png$/, '.svg'))));
  for (const n of shown) {
    const url = await blobUrl(sel, n);
    if (url) body.push(el('figure', {}, el('figcaption', {}, n), el('img', { src: url, alt: `ISO 230-2 plot ${n}` })));
  }
  if (S.sel !== sel) return;
  if (!body.length) return;
  $('iso-body').replaceChildren(...body);
  $('iso').hidden = false;
}

// Which figures to show of one axis and how they were obtained: the source the report names
// (`source`: full_scan, measured or reconstructed, with its `source_label`) when there is one,
// else the measured figures before the reconstruction's estimate.
function isoSource(v) {
  if (!v || typeof v !== 'object') return null;
  if ('a_um' in v) return { fig: v, label: v.source_label || '' };
  const pick = { full_scan: v.full_scan, measured: v.measured, reconstructed: v.reconstructed }[v.source];
  if (pick && typeof pick === 'object') return { fig: pick, label: v.source_label || v.source };
  if (v.full_scan && typeof v.full_scan === 'object') return { fig: v.full_scan, label: 'from the measured full scan' };
  if (v.measured && typeof v.measured === 'object') return { fig: v.measured, label: 'from the measured approaches' };
  if (v.reconstructed && typeof v.reconstructed === 'object') {
    return { fig: v.reconstructed, label: 'estimated from the reconstruction' };
  }
  return null;
}

function isoAxis(axis, v) {
  const src = isoSource(v);
  if (!src) return null;
  const f = src.fig;
  const figs = [
    ['A', 'accuracy', f.a_um, f.a_up_um, f.a_down_um],
    ['B', 'reversal value', f.b_um, null, null],
    ['B̄', 'mean reversal value', f.b_mean_um, null, null],
    ['E', 'systematic positioning error', f.e_um, f.e_up_um, f.e_down_um],
    ['M', 'mean positioning error', f.m_um, null, null],
    ['R', 'repeatability', f.r_um, f.r_up_um, f.r_down_um],
  ];
  const table = el('table', { class: 'iso-table', 'data-axis': axis },
    el('thead', {}, el('tr', {}, el('th', {}, 'figure'), el('th', {}, ''),
      el('th', { class: 'num' }, 'bidirectional (µm)'), el('th', { class: 'num' }, '↑ (µm)'),
      el('th', { class: 'num' }, '↓ (µm)'))),
    el('tbody', {}, ...figs.map(([k, what, b, u, d]) => el('tr', { 'data-figure': k },
      el('td', {}, k), el('td', {}, what), el('td', { class: 'num' }, fmt(b)),
      el('td', { class: 'num' }, fmt(u)), el('td', { class: 'num' }, fmt(d))))));
  const notes = (v.notes || []).map((n) => el('li', {}, n));
  const kids = [el('h4', {}, `Axis ${axis}`),
    el('p', { class: 'note' }, `${src.label}; ${f.targets ?? '?'} targets, at least ${f.min_approaches ?? '?'} approach(es) per target and direction`),
    table];
  const rows = Array.isArray(f.rows) ? f.rows : [];
  if (rows.length) kids.push(isoChart(axis, f, rows));
  if (notes.length) kids.push(el('ul', { class: 'note' }, ...notes));
  return el('div', { class: 'iso-axis', 'data-axis': axis }, ...kids);
}

// Mean positional deviation per target, forward and backward, with ±2s bands; A B E M R written on.
function isoChart(axis, f, rows) {
  const canvas = el('canvas', { width: 640, height: 320, 'data-iso': axis });
  const xs = rows.map((r) => r.target_um);
  const ys = [];
  for (const r of rows) {
    ys.push(r.mean_up_um + 2 * r.s_up_um, r.mean_up_um - 2 * r.s_up_um,
      r.mean_down_um + 2 * r.s_down_um, r.mean_down_um - 2 * r.s_down_um);
  }
  const fr = plotFrame(canvas, xs, ys.filter(isFinite), `target position, axis ${axis} (µm)`, 'mean deviation (µm)');
  const { ctx, X, Y } = fr;
  const series = [
    ['forward ↑', '#0a58ca', (r) => r.mean_up_um, (r) => r.s_up_um, (r) => r.n_up],
    ['backward ↓', '#d63384', (r) => r.mean_down_um, (r) => r.s_down_um, (r) => r.n_down],
  ];
  series.forEach(([label, color, mean, s, n], k) => {
    const rs = rows.filter((r) => n(r) > 0 && isFinite(mean(r)));
    if (!rs.length) return;
    ctx.globalAlpha = 0.15;
    ctx.fillStyle = color;
    ctx.beginPath();
    rs.forEach((r, i) => (i ? ctx.lineTo : ctx.moveTo).call(ctx, X(r.target_um), Y(mean(r) + 2 * s(r))));
    [...rs].reverse().forEach((r) => ctx.lineTo(X(r.target_um), Y(mean(r) - 2 * s(r))));
    ctx.closePath();
    ctx.fill();
    ctx.globalAlpha = 1;
    ctx.strokeStyle = color;
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    rs.forEach((r, i) => (i ? ctx.lineTo : ctx.moveTo).call(ctx, X(r.target_um), Y(mean(r))));
    ctx.stroke();
    ctx.fillStyle = color;
    ctx.textAlign = 'left';
    ctx.fillText(`${label}: mean ± 2s`, fr.L + 6, fr.T + 12 + 12 * k);
  });
  ctx.fillStyle = '#1b1f24';
  ctx.textAlign = 'right';
  const txt = [['A', f.a_um], ['B', f.b_um], ['E', f.e_um], ['M', f.m_um], ['R', f.r_um]]
    .map(([k, v]) => `${k} = ${fmt(v)} µm`);
  txt.forEach((t, k) => ctx.fillText(t, fr.W - fr.R - 6, fr.T + 12 + 12 * k));
  return el('figure', {}, el('figcaption', {}, `ISO 230-2, axis ${axis}`), canvas);
}

// ---------------------------------------------------------------- XY maps

function showMapSection(sel) {
  if (S.sel !== sel) return;
  $('maps').hidden = false;
  $('lines').hidden = sel.charts.size === 0;
}

function addMapSample(sel, s) {
  const t = s.target;
  const dir = t.run.direction;
  let list = sel.map.samples.get(dir);
  if (!list) { list = []; sel.map.samples.set(dir, list); }
  list.push([t.target_x_um, t.target_y_um, s.meas_x_um - t.target_x_um, s.meas_y_um - t.target_y_um]);
  sel.map.dirty = true;
  showMapSection(sel);
}

// Largest map file read (x fastest, one row per grid point): 2 M points.
const MAP_MAX_ROWS = 2000000;

// `map_<dir>.csv` (x_um,y_um,ex_um,ey_um[,theta_urad]) as a grid: sorted xs, ys and ex, ey
// with x fastest; null when it is not one.
function parseMapCsv(text) {
  const lines = text.split('\n');
  const head = lines[0].trim().split(',');
  const [ix, iy, iex, iey] = ['x_um', 'y_um', 'ex_um', 'ey_um'].map((k) => head.indexOf(k));
  if (Math.min(ix, iy, iex, iey) < 0 || lines.length > MAP_MAX_ROWS + 2) return null;
  const rows = [];
  for (let k = 1; k < lines.length; k++) {
    if (!lines[k]) continue;
    const f = lines[k].split(',').map(Number);
    if (isFinite(f[ix]) && isFinite(f[iy])) rows.push(f);
  }
  const axis = (i) => [...new Set(rows.map((f) => f[i]))].sort((a, b) => a - b);
  const xs = axis(ix), ys = axis(iy);
  if (!xs.length || !ys.length || xs.length * ys.length > MAP_MAX_ROWS) return null;
  const xi = new Map(xs.map((v, i) => [v, i])), yi = new Map(ys.map((v, i) => [v, i]));
  const ex = new Float64Array(xs.length * ys.length).fill(NaN);
  const ey = new Float64Array(xs.length * ys.length).fill(NaN);
  for (const f of rows) {
    const k = yi.get(f[iy]) * xs.length + xi.get(f[ix]);
    ex[k] = f[iex];
    ey[k] = f[iey];
  }
  return { xs, ys, ex, ey };
}

async function loadMapGrid(sel, dir, name) {
  if (sel.map.loading.has(name)) return;
  sel.map.loading.add(name);
  try {
    const r = await api(`/campaigns/${sel.id}/results/${encodeURIComponent(name)}`);
    if (!r.ok || S.sel !== sel) { sel.map.loading.delete(name); return; }
    const g = parseMapCsv(await r.text());
    if (!g || S.sel !== sel) return;
    sel.map.grids.set(dir, g);
    sel.map.dirty = true;
    showMapSection(sel);
    scheduleDraw(sel);
  } catch (e) {
    sel.map.loading.delete(name);
    if (!(e instanceof AuthNeeded)) notice(`${name}: ${e.message}`);
  }
}

// Blue (negative) – white – red (positive); t in [-1, 1].
function diverging(t) {
  const a = Math.min(1, Math.abs(t));
  const [r, g, b] = t < 0 ? [33, 102, 172] : [178, 24, 43];
  const mix = (c) => Math.round(255 + (c - 255) * a);
  return `rgb(${mix(r)},${mix(g)},${mix(b)})`;
}

const MAP_COMPONENTS = [['ex', 'eₓ', 2], ['ey', 'eᵧ', 3]];

function mapFig(sel, key, caption) {
  let f = sel.map.figs.get(key);
  if (f) return f;
  const canvas = el('canvas', { width: 480, height: 360, 'data-map': key, 'data-samples': 0, 'data-cells': 0 });
  f = { key, canvas, fig: el('figure', { 'data-map': key }, el('figcaption', {}, caption), canvas) };
  sel.map.figs.set(key, f);
  // Forward before backward, e_x before e_y.
  const order = (k) => (k.startsWith('forward') ? '0' : '1') + k;
  const figs = [...sel.map.figs.values()].sort((a, b) => order(a.key).localeCompare(order(b.key))).map((x) => x.fig);
  $('map-body').replaceChildren(...figs);
  return f;
}

function drawMaps(sel) {
  const dirs = new Set([...sel.map.samples.keys(), ...sel.map.grids.keys()]);
  let n = 0;
  for (const dir of dirs) {
    const pts = sel.map.samples.get(dir) || [];
    n += pts.length;
    const grid = sel.map.grids.get(dir) || null;
    for (const [comp, label, col] of MAP_COMPONENTS) {
      const caption = `${label} (µm), ${dir}, ${grid ? 'reconstructed' : 'samples so far'}`;
      const f = mapFig(sel, `${dir}-${comp}`, caption);
      f.fig.firstChild.textContent = caption;
      heatMap(f.canvas, pts, col, grid, comp);
    }
  }
  $('map-count').textContent = `${n} samples`;
}

// One error component over XY: the reconstructed grid as cells when there is one (samples as
// dots), else the samples as coloured squares; a colour bar symmetric about 0 on the right.
function heatMap(canvas, pts, col, grid, comp) {
  const ctx = canvas.getContext('2d');
  const W = canvas.width, H = canvas.height;
  const L = 58, R = 78, T = 10, B = 36;
  ctx.clearRect(0, 0, W, H);
  const span = (v) => v.reduce(([a, b], x) => [Math.min(a, x), Math.max(b, x)], [Infinity, -Infinity]);
  const xs = grid ? grid.xs : pts.map((p) => p[0]);
  const ys = grid ? grid.ys : pts.map((p) => p[1]);
  const dx = grid && grid.xs.length > 1 ? grid.xs[1] - grid.xs[0] : 0;
  const dy = grid && grid.ys.length > 1 ? grid.ys[1] - grid.ys[0] : 0;
  let [x0, x1] = span(xs), [y0, y1] = span(ys);
  if (!isFinite(x0)) [x0, x1] = [0, 1];
  if (!isFinite(y0)) [y0, y1] = [0, 1];
  x0 -= dx / 2; x1 += dx / 2; y0 -= dy / 2; y1 += dy / 2;
  if (x1 - x0 < 1e-9) { x0 -= 1; x1 += 1; }
  if (y1 - y0 < 1e-9) { y0 -= 1; y1 += 1; }
  const values = grid ? [...grid[comp]] : pts.map((p) => p[col]);
  const vmax = values.concat(pts.map((p) => p[col])).filter(isFinite)
    .reduce((m, v) => Math.max(m, Math.abs(v)), 0) || 1;
  const X = (v) => L + (v - x0) / (x1 - x0) * (W - L - R);
  const Y = (v) => H - B - (v - y0) / (y1 - y0) * (H - T - B);
  let cells = 0;
  if (grid) {
    const cw = Math.abs(X(x0 + (dx || 1)) - X(x0)) + 0.6, ch = Math.abs(Y(y0 + (dy || 1)) - Y(y0)) + 0.6;
    grid.ys.forEach((y, j) => grid.xs.forEach((x, i) => {
      const v = grid[comp][j * grid.xs.length + i];
      if (!isFinite(v)) return;
      ctx.fillStyle = diverging(v / vmax);
      ctx.fillRect(X(x) - cw / 2, Y(y) - ch / 2, cw, ch);
      cells++;
    }));
  }
  for (const p of pts) {
    if (!isFinite(p[col])) continue;
    if (grid) {
      ctx.fillStyle = '#1b1f24';
      ctx.fillRect(X(p[0]) - 1, Y(p[1]) - 1, 2, 2);
    } else {
      ctx.fillStyle = diverging(p[col] / vmax);
      ctx.fillRect(X(p[0]) - 4, Y(p[1]) - 4, 8, 8);
      ctx.strokeStyle = '#5b6570';
      ctx.lineWidth = 0.5;
      ctx.strokeRect(X(p[0]) - 4, Y(p[1]) - 4, 8, 8);
    }
  }
  ctx.font = '11px system-ui, sans-serif';
  ctx.fillStyle = '#5b6570';
  ctx.strokeStyle = '#1b1f24';
  ctx.lineWidth = 1;
  ctx.textAlign = 'center';
  for (const t of niceTicks(x0, x1, 5)) ctx.fillText(String(t), X(t), H - B + 14);
  ctx.fillText('x (µm)', (L + W - R) / 2, H - 4);
  ctx.textAlign = 'right';
  for (const t of niceTicks(y0, y1, 5)) ctx.fillText(String(t), L - 4, Y(t) + 4);
  ctx.save();
  ctx.translate(12, (T + H - B) / 2);
  ctx.rotate(-Math.PI / 2);
  ctx.textAlign = 'center';
  ctx.fillText('y (µm)', 0, 0);
  ctx.restore();
  ctx.strokeRect(L, T, W - L - R, H - T - B);
  // Colour bar.
  const bx = W - R + 12, bw = 14, bh = H - T - B;
  for (let k = 0; k < bh; k++) {
    ctx.fillStyle = diverging(1 - 2 * k / (bh - 1));
    ctx.fillRect(bx, T + k, bw, 1);
  }
  ctx.strokeRect(bx, T, bw, bh);
  ctx.fillStyle = '#5b6570';
  ctx.textAlign = 'left';
  ctx.fillText(`+${fmt(vmax)}`, bx + bw + 3, T + 10);
  ctx.fillText('0', bx + bw + 3, T + bh / 2 + 4);
  ctx.fillText(`−${fmt(vmax)}`, bx + bw + 3, T + bh);
  canvas.dataset.samples = pts.length;
  canvas.dataset.cells = cells;
  canvas.dataset.vmax = vmax;
}

// The ISO 230-1 figures of each reconstructed map (summary.json `map.runs[].iso230_1`).
async function showIso2301(sel) {
  if (sel.map.isoDone) return;
  let summary;
  try {
    summary = await getJson(`/campaigns/${sel.id}/results/summary.json`);
  } catch (e) {
    if (!(e instanceof AuthNeeded)) notice(`summary.json: ${e.message}`);
    return;
  }
  if (S.sel !== sel) return;
  const runs = summary && summary.map && Array.isArray(summary.map.runs) ? summary.map.runs : [];
  const rows = runs.filter((r) => r && r.iso230_1 && typeof r.iso230_1 === 'object');
  if (!rows.length) return;
  sel.map.isoDone = true;
  const figs = [
    ['squareness (angle − 90°)', 'µrad', 'squareness_urad', 1],
    ['straightness of X (eᵧ along x), mean profile', 'µm', 'straightness_x_um', 3],
    ['straightness of X, worst row', 'µm', 'straightness_x_worst_um', 3],
    ['straightness of Y (eₓ along y), mean profile', 'µm', 'straightness_y_um', 3],
    ['straightness of Y, worst column', 'µm', 'straightness_y_worst_um', 3],
  ];
  const table = el('table', { class: 'iso2301-table' },
    el('thead', {}, el('tr', {}, el('th', {}, 'figure'), el('th', {}, 'unit'),
      ...rows.map((r) => el('th', { class: 'num' }, String(r.direction || ''))))),
    el('tbody', {}, ...figs.map(([what, unit, key, digits]) => el('tr', { 'data-figure': key },
      el('td', {}, what), el('td', {}, unit),
      ...rows.map((r) => el('td', { class: 'num' }, fmt(r.iso230_1[key], digits)))))));
  const how = rows.map((r) => `${r.direction}: ${r.method}, ${r.m} samples, CV error ${fmt(r.cv_error_um, 4)} µm`);
  $('iso2301-body').replaceChildren(table, el('p', { class: 'note' }, `From the reconstructed map (${how.join('; ')}).`));
  $('iso2301').hidden = false;
}

// ---------------------------------------------------------------- submission

$('submit-file').addEventListener('change', async (ev) => {
  const f = ev.target.files[0];
  if (!f) return;
  if (f.size > 1 << 20) { notice(`${f.name}: larger than 1 MiB`); return; }
  $('submit-text').value = await f.text();
  $('submit-name').value = f.name;
});

$('submit-form').addEventListener('submit', async (ev) => {
  ev.preventDefault();
  const text = $('submit-text').value;
  const name = $('submit-name').value.trim() || 'campaign.toml';
  $('submit-error').hidden = true;
  try {
    const r = await api('/campaigns', {
      method: 'POST',
      headers: { 'Content-Type': 'application/json' },
      body: JSON.stringify({ toml: text, name }),
    });
    if (!r.ok) {
      showSubmitError(text, await errorOf(r));
      return;
    }
    const st = await r.json();
    await refreshList();
    select(st.id);
  } catch (e) {
    if (!(e instanceof AuthNeeded)) showSubmitError(text, e.message);
  }
});

// A validation error (`file.toml:LINE: key: why`) shown at its line of the file.
function showSubmitError(text, msg) {
  $('submit-error-msg').textContent = msg;
  const m = /^[^:\n]*:(\d+):/.exec(msg);
  const at = m ? Number(m[1]) : 0;
  const lines = text.split('\n');
  const listing = $('submit-listing');
  listing.replaceChildren();
  if (at >= 1 && at <= lines.length) {
    const from = Math.max(1, at - 3), to = Math.min(lines.length, at + 3);
    for (let i = from; i <= to; i++) {
      const row = el('span', { 'data-line': i }, `${String(i).padStart(4)} | ${lines[i - 1]}\n`);
      if (i === at) { row.className = 'err'; row.id = 'submit-error-line'; }
      listing.append(row);
    }
    // Put the cursor on the line in the editor too.
    const ta = $('submit-text');
    const start = lines.slice(0, at - 1).reduce((n, l) => n + l.length + 1, 0);
    ta.setSelectionRange(start, start + lines[at - 1].length);
  }
  $('submit-error').hidden = false;
}

// ---------------------------------------------------------------- start

function start() {
  refreshList().then(() => {
    const id = Number(location.hash.slice(1));
    if (id && S.list.some((c) => c.id === id)) select(id);
    else if (!S.sel) {
      // The running campaign, else the newest one.
      const c = S.list.find((x) => x.state === 'running') || S.list[0];
      if (c) select(c.id);
    }
  });
  if (!S.listTimer) {
    S.listTimer = setInterval(() => {
      refreshList();
      // Plots and tables that appear during a run (and at its end); a finished campaign's
      // results were read at its end.
      if (S.sel && (S.sel.live || !S.sel.resultsKey)) loadResults(S.sel);
    }, LIST_EVERY_MS);
  }
}

start();
