// pkmc operator station: the scope panel. Plain ES2020, no libraries: the traces are
// drawn on the server (plotters, the drawing of `nc-send record --plot`) as SVG for
// the time range shown; this script asks for them, and draws the zoom selection and
// the two cursors over them with the drawing's pixel mapping that comes along.
'use strict';
(() => {

const $ = (id) => document.getElementById(id);
const pkmc = window.pkmc;
const SVG_NS = 'http://www.w3.org/2000/svg';
/** Live, a new drawing at most this often (ms): the server draws it, and the
 * machine's own work comes first. */
const LIVE_REDRAW = 200;
/** A drawing asked for and not come within this long is given up (ms). */
const PLOT_TIMEOUT = 3000;
/** A press that moves less than this is a click (cursor), more a zoom (pixels). */
const DRAG_PX = 4;
/** A cursor within this many pixels of a press is dragged. */
const GRAB_PX = 6;

const scope = pkmc.scope = {
  state: null, // the last `scope` message
  plot: null, // the last `scope_plot` message
  asked: 0, // when a drawing was asked (0: none in flight)
  readyAt: 0, // live: no new drawing asked before this (performance.now())
  timer: null, // the ask waiting for readyAt
  dirty: false, // ask again when the one in flight comes
  range: null, // zoom: [t0, t1] s, or null (all; the window while live)
  cursors: [null, null], // A and B, s
  next: 0, // the cursor a click places (0: A, 1: B)
  ids: new Set(), // this panel's command ids
  press: null, // a press on the traces: {x, shift, grab, moved}
};

// ================================================================ messages

function onScope(m) {
  const before = scope.state;
  scope.state = m;
  const error = m.error || '';
  $('scope-error').textContent = error ? `Scope: ${error}` : '';
  const info = { off: 'stopped', live: 'live', armed: 'armed: waiting for the trigger', done: 'capture' }[m.mode] || '';
  const n = m.samples ? ` · ${m.samples} samples` : '';
  const lost = m.missing ? ` · ${m.missing} lost` : '';
  $('scope-info').textContent = info + n + lost;
  $('scope-live').classList.toggle('active', m.mode === 'live');
  $('scope-arm').classList.toggle('active', m.mode === 'armed');
  if (!before) {
    // A page that connects takes the panel's request as it stands.
    $('scope-signals').value = m.signals;
    if (m.trigger !== 'stream') $('scope-trigger').value = m.trigger;
    if (m.pre) $('scope-pre').value = m.pre;
    $('scope-decimate').value = m.decimate;
  }
  const newRun = before && before.mode !== m.mode && (m.mode === 'live' || m.mode === 'armed');
  if (newRun) {
    scope.range = null;
    scope.cursors = [null, null];
    chooseCursor(0);
  }
  if (m.samples > 0 && (!scope.plot || scope.plot.version !== m.version)) askPlot();
}

function onPlot(m) {
  scope.asked = 0;
  scope.plot = m;
  const box = $('scope-svg');
  box.classList.remove('muted');
  box.innerHTML = m.svg;
  const over = $('scope-over');
  over.setAttribute('width', m.layout.width);
  over.setAttribute('height', m.layout.height);
  over.setAttribute('viewBox', `0 0 ${m.layout.width} ${m.layout.height}`);
  drawOver();
  renderReadout();
  const live = scope.state && scope.state.mode === 'live';
  scope.readyAt = performance.now() + (live ? LIVE_REDRAW : 0);
  if (scope.dirty || (scope.state && scope.state.version !== m.version)) askPlot();
}

/** Replies to this panel's commands: a refusal is shown on the panel too. */
function onReply(r) {
  if (!scope.ids.has(r.id)) return;
  scope.ids.delete(r.id);
  if (!r.ok) {
    $('scope-error').textContent = `Scope: ${r.text}`;
    scope.asked = 0;
  }
}

const appReply = pkmc.handlers.reply;
pkmc.handlers.reply = (r) => {
  onReply(r);
  appReply(r);
};
pkmc.handlers.scope = onScope;
pkmc.handlers.scope_plot = onPlot;

function command(cmd, args = {}) {
  const id = pkmc.send(cmd, args);
  if (id !== null) scope.ids.add(id);
  return id;
}

/** Asks for a drawing of the range shown (one in flight at a time). */
function askPlot() {
  if (scope.asked && performance.now() - scope.asked < PLOT_TIMEOUT) {
    scope.dirty = true;
    return;
  }
  if (!$('scope-panel').open) {
    scope.dirty = true;
    return;
  }
  const wait = scope.readyAt - performance.now();
  if (wait > 0) {
    scope.dirty = true;
    if (!scope.timer) {
      scope.timer = setTimeout(() => {
        scope.timer = null;
        askPlot();
      }, wait);
    }
    return;
  }
  scope.dirty = false;
  const width = Math.max(320, $('scope-plot').clientWidth - 2);
  const args = { width, from: null, to: null, window: null };
  if (scope.range) [args.from, args.to] = scope.range;
  else if (scope.state && scope.state.mode === 'live') args.window = Number($('scope-window').value) || 5;
  if (command('scope_view', args) !== null) scope.asked = performance.now();
}

// ================================================================ request

function arm(live) {
  $('scope-error').textContent = '';
  command('scope_arm', {
    signals: $('scope-signals').value,
    trigger: live ? 'stream' : $('scope-trigger').value,
    pre: live ? 0 : Number($('scope-pre').value),
    decimate: Number($('scope-decimate').value),
  });
}

// ================================================================ cursors and zoom

/** The drawing's time at pixel x, and back. */
function timeAt(x) {
  const l = scope.plot.layout;
  return l.t0 + (x - l.x0) / (l.x1 - l.x0) * (l.t1 - l.t0);
}
function xAt(t) {
  const l = scope.plot.layout;
  return l.x0 + (t - l.t0) / (l.t1 - l.t0) * (l.x1 - l.x0);
}

/** The index of the sample drawn nearest to time t. */
function nearest(t) {
  const ts = scope.plot.times;
  if (!ts.length) return -1;
  let lo = 0;
  let hi = ts.length - 1;
  while (hi - lo > 1) {
    const mid = (lo + hi) >> 1;
    if (ts[mid] <= t) lo = mid; else hi = mid;
  }
  return Math.abs(ts[hi] - t) < Math.abs(ts[lo] - t) ? hi : lo;
}

function svgEl(tag, attrs) {
  const e = document.createElementNS(SVG_NS, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  return e;
}

/** The cursors (a line through every panel, a dot on each trace) and the selection. */
function drawOver() {
  const over = $('scope-over');
  over.replaceChildren();
  const p = scope.plot;
  if (!p) return;
  const l = p.layout;
  const top = l.panels.length ? l.panels[0].top : 0;
  const bottom = l.panels.length ? l.panels[l.panels.length - 1].bottom : l.height;
  scope.cursors.forEach((t, c) => {
    if (t === null || t < l.t0 || t > l.t1) return;
    const x = xAt(t);
    const cls = `cur cur-${'ab'[c]}`;
    over.append(svgEl('line', { x1: x, x2: x, y1: top - 14, y2: bottom, class: cls }));
    const label = svgEl('text', { x: x + 3, y: top - 4, class: cls });
    label.textContent = 'AB'[c];
    over.append(label);
    const i = nearest(t);
    l.panels.forEach((pl, k) => {
      if (i < 0) return;
      const v = p.values[k][i];
      const y = pl.bottom - (v - pl.low) / (pl.high - pl.low) * (pl.bottom - pl.top);
      over.append(svgEl('circle', { cx: xAt(p.times[i]), cy: y, r: 3, class: cls }));
    });
  });
  const s = scope.press;
  if (s && s.moved && s.grab === null) {
    const [a, b] = [Math.min(s.x, s.to), Math.max(s.x, s.to)];
    over.append(svgEl('rect', { x: a, y: top, width: b - a, height: bottom - top, class: 'sel' }));
  }
}

function fmt(v, digits) {
  return typeof v === 'number' && Number.isFinite(v) ? v.toFixed(digits) : '—';
}

/** The cursors' table: their times, each trace's value at them, and B − A. */
function renderReadout() {
  const table = $('scope-cursors');
  table.replaceChildren();
  const p = scope.plot;
  if (!p || (scope.cursors[0] === null && scope.cursors[1] === null)) return;
  const at = scope.cursors.map((t) => (t === null ? -1 : nearest(t)));
  const row = (cells, tag = 'td') => {
    const tr = document.createElement('tr');
    cells.forEach(([text, cls]) => {
      const c = document.createElement(tag);
      c.textContent = text;
      if (cls) c.className = cls;
      tr.append(c);
    });
    table.append(tr);
  };
  row([['', ''], ['A', 'a'], ['B', 'b'], ['B − A', '']], 'th');
  const times = at.map((i) => (i < 0 ? null : p.times[i]));
  const dt = times[0] !== null && times[1] !== null ? times[1] - times[0] : null;
  row([['t_s', ''], [fmt(times[0], 6), 'a'], [fmt(times[1], 6), 'b'], [fmt(dt, 6), '']]);
  p.columns.forEach((name, k) => {
    const v = at.map((i) => (i < 0 ? null : p.values[k][i]));
    const d = v[0] !== null && v[1] !== null ? v[1] - v[0] : null;
    row([[name, ''], [fmt(v[0], 0), 'a'], [fmt(v[1], 0), 'b'], [fmt(d, 0), '']]);
  });
}

function pointerX(e) {
  return e.clientX - $('scope-over').getBoundingClientRect().left;
}

function onDown(e) {
  if (!scope.plot || e.button !== 0) return;
  const x = pointerX(e);
  let grab = null;
  scope.cursors.forEach((t, c) => {
    if (t !== null && Math.abs(xAt(t) - x) <= GRAB_PX) grab = c;
  });
  scope.press = { x, to: x, shift: e.shiftKey, grab, moved: false };
  $('scope-over').setPointerCapture(e.pointerId);
  e.preventDefault();
}

function onMove(e) {
  const s = scope.press;
  if (!s) return;
  s.to = pointerX(e);
  s.moved = s.moved || Math.abs(s.to - s.x) > DRAG_PX;
  if (s.grab !== null) scope.cursors[s.grab] = timeAt(s.to);
  drawOver();
  if (s.grab !== null) renderReadout();
}

function onUp() {
  const s = scope.press;
  scope.press = null;
  if (!s) return;
  if (s.grab === null && s.moved) {
    const [a, b] = [timeAt(Math.min(s.x, s.to)), timeAt(Math.max(s.x, s.to))];
    scope.range = [a, b];
    askPlot();
  } else if (s.grab === null) {
    const c = s.shift ? 1 : scope.next;
    scope.cursors[c] = timeAt(s.x);
    if (c === 0) chooseCursor(1);
  }
  drawOver();
  renderReadout();
}

function chooseCursor(c) {
  scope.next = c;
  $('scope-cur-a').classList.toggle('active', c === 0);
  $('scope-cur-b').classList.toggle('active', c === 1);
}

// ================================================================ start-up

function csvHref() {
  const token = new URLSearchParams(location.search).get('token');
  return token === null ? '/scope.csv' : `/scope.csv?token=${encodeURIComponent(token)}`;
}

function init() {
  $('scope-live').addEventListener('click', () => arm(true));
  $('scope-arm').addEventListener('click', () => arm(false));
  $('scope-stop').addEventListener('click', () => command('scope_stop'));
  $('scope-full').addEventListener('click', () => {
    scope.range = null;
    askPlot();
  });
  $('scope-window').addEventListener('change', askPlot);
  $('scope-cur-a').addEventListener('click', () => chooseCursor(0));
  $('scope-cur-b').addEventListener('click', () => chooseCursor(1));
  $('scope-panel').addEventListener('toggle', () => {
    if ($('scope-panel').open && scope.state && scope.state.samples) askPlot();
  });
  $('scope-csv').href = csvHref();
  const over = $('scope-over');
  over.addEventListener('pointerdown', onDown);
  over.addEventListener('pointermove', onMove);
  over.addEventListener('pointerup', onUp);
  over.addEventListener('pointercancel', () => { scope.press = null; drawOver(); });
  // A drawing that never came (the connection dropped): ask again.
  setInterval(() => {
    if (scope.asked && performance.now() - scope.asked > PLOT_TIMEOUT) {
      scope.asked = 0;
      askPlot();
    }
  }, 1000);
}

init();
})();
