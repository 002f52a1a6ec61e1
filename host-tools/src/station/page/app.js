// pkmc operator station: the page's script. Plain ES2020, no libraries.
// Sections: utilities, shared state, connection, message handlers, DRO, program
// panel, jog / MDI / joint moves, teach list, log and toast, 3-D view, start-up.
'use strict';
(() => {

// ===================================================================== utilities

const $ = (id) => document.getElementById(id);
const AXES = ['X', 'Y', 'Z', 'A', 'B', 'C'];
const STATS_CAP = 100000;

/** Sets an element's text only when it changed (status arrives at 50 Hz). */
function setText(el, s) {
  if (el && el.textContent !== s) el.textContent = s;
}

/** A number with 3 decimals, "-0.000" shown as "0.000". */
function fmt3(v) {
  if (typeof v !== 'number' || !Number.isFinite(v)) return '—';
  return Math.abs(v) < 0.0005 ? '0.000' : v.toFixed(3);
}

/** Seconds as m:ss ("—" when unknown). */
function mmss(s) {
  if (typeof s !== 'number' || !Number.isFinite(s)) return '—';
  const t = Math.max(0, Math.round(s));
  return `${Math.floor(t / 60)}:${String(t % 60).padStart(2, '0')}`;
}

function pushCapped(arr, v) {
  if (arr.length >= STATS_CAP) arr.splice(0, arr.length - STATS_CAP + 1);
  arr.push(v);
}

function el(tag, cls, text) {
  const e = document.createElement(tag);
  if (cls) e.className = cls;
  if (text !== undefined) e.textContent = text;
  return e;
}

// ================================================================== shared state

const params = new URLSearchParams(location.search);
const TOKEN = params.get('token');
const CLIENT_NAME = params.get('name') ||
  'browser-' + Math.floor(Math.random() * 0x10000).toString(16).padStart(4, '0');

const pkmc = window.pkmc = {
  stats: { frames: [], status: [], draw: [], handle: [], longtasks: [], slow: [] },
  lastStatus: null, program: null, machine: null, teach: null, probes: null,
  you: null, lock: null, log: [], alarms: [], jogEnabled: true,
};

const conn = {
  ws: null, nextId: 0, heartbeat: null, pending: new Map(),
  firstStatus: true, userReleased: false,
};

// ==================================================================== connection

function wsUrl() {
  const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
  let url = `${proto}//${location.host}/ws?name=${encodeURIComponent(CLIENT_NAME)}`;
  if (TOKEN !== null) url += `&token=${encodeURIComponent(TOKEN)}`;
  return url;
}

function connect() {
  let ws;
  try {
    ws = new WebSocket(wsUrl());
  } catch (e) {
    setTimeout(connect, 1000);
    return;
  }
  conn.ws = ws;
  ws.onopen = () => {
    conn.firstStatus = true;
    setConnected(true);
    conn.heartbeat = setInterval(() => send('heartbeat'), 250);
  };
  ws.onmessage = (ev) => onMessage(ev.data);
  ws.onerror = () => {}; // a close event follows
  ws.onclose = () => {
    if (conn.ws !== ws) return;
    conn.ws = null;
    clearInterval(conn.heartbeat);
    jog.active = false;
    setConnected(false);
    setTimeout(connect, 1000);
  };
}

function setConnected(up) {
  const c = $('conn');
  c.classList.toggle('down', !up);
  c.classList.toggle('up', up);
  setText(c, up ? 'connected' : 'disconnected — reconnecting…');
  document.body.classList.toggle('offline', !up);
}

/** Sends one command with a fresh id; returns the id (null when not connected). */
function send(cmd, args = {}) {
  const ws = conn.ws;
  if (!ws || ws.readyState !== WebSocket.OPEN) {
    if (cmd !== 'heartbeat') toast(`not connected: ${cmd} not sent`);
    return null;
  }
  const id = ++conn.nextId;
  ws.send(JSON.stringify({ cmd, id, ...args }));
  if (cmd === 'heartbeat') return id; // the server does not answer heartbeats
  conn.pending.set(id, cmd);
  if (conn.pending.size > 1000) conn.pending.delete(conn.pending.keys().next().value);
  return id;
}

const HANDLERS = {
  hello: onHello, status: onStatus, program: onProgram, teach: onTeach,
  reply: onReply, log: (m) => addLog(m.level, m.text), file: onFile, probes: onProbes,
  probe: onMdiProbe,
};

// The scope panel's script (scope.js) sends and receives through these.
pkmc.send = send;
pkmc.handlers = HANDLERS;

function onMessage(data) {
  const t0 = performance.now();
  const type = handleMessage(data);
  const ms = performance.now() - t0;
  pushCapped(pkmc.stats.handle, ms);
  if (ms > 20) pushCapped(pkmc.stats.slow, { type, ms, at: t0 });
}

// Tasks of the page over 50 ms, as the browser reports them (where supported).
try {
  new PerformanceObserver((list) => {
    for (const e of list.getEntries()) pushCapped(pkmc.stats.longtasks, e.duration);
  }).observe({ type: 'longtask', buffered: true });
} catch (e) { /* no long-task timing in this browser */ }

function handleMessage(data) {
  let msg;
  try {
    msg = JSON.parse(data);
  } catch (e) {
    addLog('error', 'unreadable message from the server');
    return undefined;
  }
  const h = HANDLERS[msg && msg.type];
  if (!h) return undefined;
  try {
    h(msg);
  } catch (e) {
    addLog('error', `page error handling "${msg.type}": ${e.message}`);
  }
  return msg.type;
}

// ============================================================== message handlers

function onHello(msg) {
  const m = msg.machine || {};
  pkmc.you = msg.you;
  pkmc.machine = m;
  setText($('machine-name'), m.name || '—');
  setText($('machine-kind'), m.kind || '');
  document.title = `${m.name || 'pkmc'} · operator station`;
  const axes = m.axes || AXES;
  buildDro(axes);
  buildJoints(m.joints || []);
  buildJogButtons(axes);
  buildJointSelect(m.joints || []);
  view.setBounds(m.bounds);
}

function onStatus(st) {
  pushCapped(pkmc.stats.status, performance.now());
  pkmc.lastStatus = st;
  pkmc.lock = st.lock || null;
  if (st.scene) view.scene = st.scene;
  updateDro(st);
  updateJoints(st);
  updateMachineState(st);
  updateLock(st.lock);
  updateJob(st.job);
  updateEnables();
  updateOverride(st.override);
  highlightLine(st);
  recordCut(st);
  if (conn.firstStatus) {
    conn.firstStatus = false;
    if (!conn.userReleased && st.lock && st.lock.holder == null) send('take');
  }
}

function onReply(r) {
  const cmd = conn.pending.get(r.id);
  conn.pending.delete(r.id);
  if (r.ok) return;
  const why = r.text || 'refused';
  const text = cmd && !why.startsWith(cmd) ? `${cmd}: ${why}` : why;
  addLog('error', text);
  toast(text);
}

/** A file the server wants saved (the teach list): download it. */
function onFile(f) {
  const blob = new Blob([f.text || ''], { type: 'text/plain' });
  const a = document.createElement('a');
  a.href = URL.createObjectURL(blob);
  a.download = f.name || 'teach.txt';
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(a.href), 2000);
  addLog('info', `saved ${a.download}`);
}

// =========================================================================== DRO

const dro = { cells: [], joints: [] };

function buildDro(axes) {
  dro.cells = AXES.map((ax) => $('dro-' + ax.toLowerCase()));
  document.querySelectorAll('#dro .dro-row').forEach((row) => {
    row.hidden = !axes.includes(row.dataset.axis);
  });
}

function buildJoints(joints) {
  const body = $('dro-joints').tBodies[0];
  body.replaceChildren();
  dro.joints = joints.map((j, i) => {
    const tr = el('tr');
    tr.dataset.joint = String(i);
    const bar = el('div', 'bar');
    const mark = el('div', 'mark');
    bar.appendChild(mark);
    const cells = {
      name: el('td', 'name', j.name), cmd: el('td', 'cmd num', '0.000'),
      meas: el('td', 'meas num', '0.000'), unit: el('td', 'unit', j.unit || ''),
      range: el('td', 'range'),
    };
    if (j.home != null && j.max > j.min) {
      const h = el('div', 'home');
      h.style.left = (100 * (j.home - j.min) / (j.max - j.min)).toFixed(1) + '%';
      bar.appendChild(h);
    }
    cells.range.appendChild(bar);
    cells.range.title = `${j.min} … ${j.max} ${j.unit || ''}`;
    Object.values(cells).forEach((c) => tr.appendChild(c));
    body.appendChild(tr);
    return {
      ...cells, bar, mark, min: j.min, max: j.max, home: j.home, pct: -1,
      linear: j.unit === 'mm', unitName: j.unit || '',
    };
  });
}

function updateDro(st) {
  const pose = st.pose || [];
  dro.cells.forEach((c, i) => setText(c, i < 3 ? fmtLen(pose[i]) : fmt3(pose[i])));
  setText($('line'), String(st.line ?? 0));
  setText($('feed'), typeof st.feed === 'number'
    ? (st.feed / lengthScale()).toFixed(units.inch ? 1 : 0) : '—');
  setText($('override-value'), `${st.override ?? 100}%`);
  setText($('buffered'), String(st.buffered_ms ?? 0));
  setText($('homed'), homedText(st.homed));
}

function homedText(h) {
  if (Array.isArray(h)) {
    const n = h.filter(Boolean).length;
    return n === h.length ? 'yes' : `${n}/${h.length}`;
  }
  return h ? 'yes' : 'no';
}

function updateJoints(st) {
  const cmd = st.joints || [];
  const meas = st.measured || [];
  dro.joints.forEach((j, i) => {
    const f = j.linear ? fmtLen : fmt3;
    setText(j.cmd, f(cmd[i]));
    setText(j.meas, f(meas[i]));
    const span = j.max - j.min;
    if (!(span > 0) || typeof cmd[i] !== 'number') return;
    const pct = Math.min(100, Math.max(0, (100 * (cmd[i] - j.min)) / span));
    if (Math.abs(pct - j.pct) < 0.1) return;
    j.pct = pct;
    j.mark.style.left = pct.toFixed(1) + '%';
    // Red near either end of the travel, except at the joint's home (a joint may home
    // at an end of its travel: there it is where it should be, and says so).
    const atHome = j.home != null && Math.abs(cmd[i] - j.home) <= 0.005 * span;
    j.bar.classList.toggle('at-home', atHome);
    j.bar.classList.toggle('near', !atHome && (pct < 5 || pct > 95));
    j.range.title = `${j.min} … ${j.max} ${j.unitName}` +
      (j.home != null ? `, home ${j.home}` : '') + (atHome ? ' (at home)' : '');
  });
}

/** The state badge: the core's words as the station sends them (`state_words`); an
 *  e-stop says E-STOP. `state` is the state's stable name, for the page's logic. */
function updateMachineState(st) {
  const s = $('state');
  const a = st.alarm;
  const estop = st.state === 'EStop' || !!(a && a.estop);
  setText(s, estop ? 'E-STOP' : (st.state_words || '—'));
  const cls = 'badge st-' + (estop ? 'estop' : String(st.state || 'none').toLowerCase());
  if (s.className !== cls) s.className = cls;
  let text = '';
  if (a) {
    const where = [a.joint ? `joint ${a.joint}` : '', a.line ? `line ${a.line}` : '']
      .filter(Boolean).join(', ');
    text = `${a.title || a.words}${where ? ' (' + where + ')' : ''}. ${a.next || ''}`;
  }
  setText($('alarm'), text);
  const now = $('alarm-now');
  now.classList.toggle('on', !!a);
  if (!a) {
    setText(now, 'No alarm.');
    alarms.key = '';
    return;
  }
  const key = `${a.title}|${a.joint}|${a.line}|${a.cause}`;
  if (key === alarms.key) return;
  alarms.key = key;
  now.replaceChildren(el('span', '', text.split('. ')[0] + '.'), el('span', 'next', a.next || ''));
  const li = el('li');
  const t = el('time', '', new Date().toTimeString().slice(0, 8));
  li.append(t, `${a.title || a.words}${a.line ? ' at line ' + a.line : ''}${a.joint ? ', joint ' + a.joint : ''}`);
  li.title = a.next || '';
  $('alarm-history').prepend(li);
  pkmc.alarms.push({ title: a.title, cause: a.cause, line: a.line, joint: a.joint, next: a.next });
}

const alarms = { key: '' };

/** Run and Jog are offered only where the controller would take them: no alarm, no
 *  e-stop, not homing; Run also needs a program without errors and no job. */
function updateEnables() {
  const st = pkmc.lastStatus || {};
  const p = pkmc.program;
  const locked = ['Alarm', 'EStop', 'Homing'].includes(st.state);
  const bad = !p || (p.errors || []).length > 0;
  const job = st.job;
  const busy = !!job || ['Running', 'Hold'].includes(st.state);
  const stepping = !!(job && job.step);
  const set = (b, off) => { if (b.disabled !== off) b.disabled = off; };
  set($('run'), bad || locked || busy);
  // A program that probes runs only as a whole, a stage at a time.
  set($('step'), bad || !!(p && p.probing) || locked || (busy && !stepping));
  const jogOff = locked || (!!job && !['jog', 'jog_hold', 'joint'].includes(job.kind));
  document.querySelectorAll('#jog-buttons button, #joint-minus, #joint-plus, #mdi-send, #teach-run, #teach-step')
    .forEach((b) => set(b, jogOff));
  pkmc.jogEnabled = !jogOff;
}

function updateLock(lock) {
  const l = $('lock');
  let who = 'nobody';
  if (lock && lock.holder != null) {
    who = lock.holder === pkmc.you ? 'you' : (lock.name || `#${lock.holder}`);
  }
  setText(l, who);
  l.className = who === 'you' ? 'mine' : who === 'nobody' ? 'free' : 'other';
}

function updateJob(job) {
  const p = $('progress');
  $('step').classList.toggle('waiting', !!(job && job.step));
  if (!job) {
    if (p.value !== 0) p.value = 0;
    setText($('progress-text'), '—');
    setText($('eta'), '—');
    return;
  }
  const pct = Number(job.percent) || 0;
  if (Math.abs(p.value - pct) > 0.05) p.value = pct;
  setText($('progress-text'), `${job.executed}/${job.total}  ${Math.round(pct)}%`);
  setText($('eta'), mmss(job.eta_s));
}

// ================================================================= program panel

const prog = { overrideTouched: 0, overrideHeld: false, lineAt: 0, lh: 0 };

function countLines(text) {
  let n = 1;
  for (let i = text.indexOf('\n'); i !== -1; i = text.indexOf('\n', i + 1)) n++;
  return n;
}

/** The gutter: line count, marks (line -> class and message) and the executing line.
 * Only the numbers in view are in the page (a CAM program has tens of thousands of
 * lines, and a div per line made every restyle of the page slow). */
const gut = { lines: 1, marks: new Map(), cur: 0, charW: 0, cols: new Map() };

/** The editor's character width (monospace), measured once. */
function charWidth() {
  if (!gut.charW) {
    const probe = el('span', '', 'M'.repeat(100));
    const cs = getComputedStyle($('editor'));
    probe.style.cssText = `position:absolute;visibility:hidden;white-space:pre;font:${cs.font}`;
    document.body.appendChild(probe);
    gut.charW = probe.getBoundingClientRect().width / 100 || 7.2;
    probe.remove();
  }
  return gut.charW;
}

/** Lines under the words at the errors' columns, for the lines in view. */
function renderMarks(first, last) {
  const ed = $('editor');
  const lh = lineHeight();
  const cw = charWidth();
  const cs = getComputedStyle(ed);
  const padTop = parseFloat(cs.paddingTop) || 0;
  const padLeft = parseFloat(cs.paddingLeft) || 0;
  const text = ed.value;
  const frag = document.createDocumentFragment();
  for (const [line, m] of gut.marks) {
    if (line < first || line > last) continue;
    const col = gut.cols.get(line) || 1;
    const lineText = lineOf(text, line);
    // The word at the column: up to the next blank (at least one character).
    const rest = lineText.slice(col - 1);
    const len = Math.max(1, (rest.match(/^\S+/) || [''])[0].length);
    const d = el('div', `mark ${m.cls}`);
    d.dataset.line = String(line);
    d.dataset.col = String(col);
    d.title = m.message;
    d.style.left = `${padLeft + (col - 1) * cw - ed.scrollLeft}px`;
    d.style.top = `${padTop + line * lh - 2 - ed.scrollTop}px`;
    d.style.width = `${len * cw}px`;
    frag.appendChild(d);
  }
  $('marks').replaceChildren(frag);
}

/** Line `n` (1-based) of `text`. */
function lineOf(text, n) {
  let start = 0;
  for (let i = 1; i < n; i++) {
    const k = text.indexOf('\n', start);
    if (k < 0) return '';
    start = k + 1;
  }
  const end = text.indexOf('\n', start);
  return text.slice(start, end < 0 ? text.length : end);
}

function syncGutter() {
  gut.lines = countLines($('editor').value);
  renderGutter();
  updateDirty();
}

/** Draws the line numbers in view, scrolled with the editor. */
function renderGutter() {
  const gutter = $('gutter');
  const ed = $('editor');
  const lh = lineHeight();
  const first = Math.max(1, Math.floor(ed.scrollTop / lh));
  const last = Math.min(gut.lines, first + Math.ceil(ed.clientHeight / lh) + 2);
  const spacer = el('div', 'spacer');
  spacer.style.height = `${(first - 1) * lh}px`;
  const frag = document.createDocumentFragment();
  frag.appendChild(spacer);
  for (let i = first; i <= last; i++) {
    const d = el('div', '', String(i));
    d.dataset.line = String(i);
    const m = gut.marks.get(i);
    if (m) {
      d.classList.add(m.cls);
      d.title = m.message;
    }
    if (i === gut.cur) d.classList.add('cur');
    frag.appendChild(d);
  }
  gutter.replaceChildren(frag);
  gutter.scrollTop = ed.scrollTop;
  renderMarks(first, last);
}

function updateDirty() {
  const loaded = pkmc.program ? pkmc.program.text : '';
  $('load-editor').classList.toggle('dirty', $('editor').value !== loaded);
}

function onProgram(p) {
  pkmc.program = p;
  setText($('program-name'), p.name || '—');
  setText($('program-info'), `${p.lines ?? '?'} lines · ${p.blocks ?? '?'} blocks`);
  const ed = $('editor');
  if (ed.value !== p.text) {
    ed.value = p.text || '';
    ed.scrollTop = 0;
  }
  syncGutter();
  gut.cur = 0;
  renderErrors(p);
  renderCheck(p.check);
  updateEnables();
  view.setProgramPath(p.path || [], (p.errors || []).map((e) => e.line));
  renderProbes();
}

function renderErrors(p) {
  const ul = $('errors');
  gut.marks.clear();
  gut.cols.clear();
  const items = [];
  for (const e of p.errors || []) {
    const li = el('li', 'error', `${e.line}:${e.col}: ${e.message}`);
    li.dataset.line = String(e.line);
    li.dataset.col = String(e.col);
    items.push(li);
    markGutter(e.line, 'err', e.message);
    if (!gut.cols.has(e.line)) gut.cols.set(e.line, e.col);
  }
  for (const f of (p.check && p.check.findings) || []) {
    const li = el('li', 'finding', `${f.line}: ${f.message}`);
    li.dataset.line = String(f.line);
    items.push(li);
    markGutter(f.line, 'warn', f.message);
  }
  ul.replaceChildren(...items.slice(0, 1000));
  renderGutter();
  ul.classList.toggle('empty', items.length === 0);
}

function markGutter(line, cls, message) {
  const m = gut.marks.get(line);
  if (m && m.cls === 'err') return;
  gut.marks.set(line, { cls, message });
}

function renderCheck(check) {
  const res = $('check-result');
  const mar = $('margin');
  if (!check) {
    setText(res, '—');
    setText(mar, '—');
    res.className = 'v';
    return;
  }
  const first = (check.findings || [])[0];
  if (check.ok) setText(res, `ok, run time ${mmss(check.run_time_s)}`);
  else setText(res, first ? `line ${first.line}: ${first.message}` : 'failed');
  res.className = 'v ' + (check.ok ? 'ok' : 'bad');
  if (typeof check.min_margin === 'number') {
    const at = check.margin_line != null ? ` (line ${check.margin_line})` : '';
    setText(mar, fmt3(check.min_margin) + at);
  } else {
    setText(mar, '—');
  }
}

/** Selects line/column (1-based) in the editor and scrolls it into view. */
function selectInEditor(line, col) {
  const ed = $('editor');
  const text = ed.value;
  let start = 0;
  for (let i = 1; i < line; i++) {
    const k = text.indexOf('\n', start);
    if (k < 0) break;
    start = k + 1;
  }
  let end = text.indexOf('\n', start);
  if (end < 0) end = text.length;
  const from = col ? Math.min(start + col - 1, end) : start;
  ed.focus();
  ed.setSelectionRange(from, Math.max(end, from));
  scrollEditorTo(line);
}

/** The editor's line height (read once: reading it forces a style pass). */
function lineHeight() {
  if (!prog.lh) prog.lh = parseFloat(getComputedStyle($('editor')).lineHeight) || 18;
  return prog.lh;
}

function scrollEditorTo(line) {
  const ed = $('editor');
  const lh = lineHeight();
  ed.scrollTop = Math.max(0, (line - 1) * lh - ed.clientHeight / 3);
  renderGutter();
}

/** Marks the executing line in the gutter; follows it while running. */
function highlightLine(st) {
  const line = st.line || 0;
  if (line === gut.cur) return;
  // A CAM program changes line 50 times a second: the gutter and the editor follow
  // at most 8 times a second.
  const now = performance.now();
  if (now - prog.lineAt < 125 && st.state === 'Running') return;
  prog.lineAt = now;
  gut.cur = line;
  const ed = $('editor');
  const following = st.job && (st.job.kind === 'program' || st.job.kind === 'step');
  if (following && document.activeElement !== ed) {
    const lh = lineHeight();
    const y = (line - 1) * lh;
    if (y < ed.scrollTop || y > ed.scrollTop + ed.clientHeight - 2 * lh) scrollEditorTo(line);
  }
  renderGutter();
}

function updateOverride(percent) {
  if (typeof percent !== 'number') return;
  if (prog.overrideHeld || performance.now() - prog.overrideTouched < 1500) return;
  const r = $('override');
  if (Number(r.value) !== percent) r.value = String(percent);
  setText($('override-set'), `${r.value}%`);
}

function loadFileInput(input, cmd) {
  const f = input.files && input.files[0];
  if (!f) return;
  f.text().then((text) => {
    send(cmd, { name: f.name, text });
    input.value = '';
  }, (e) => addLog('error', `cannot read ${f.name}: ${e.message}`));
}

function initProgramPanel() {
  const ed = $('editor');
  ed.addEventListener('input', syncGutter);
  ed.addEventListener('scroll', renderGutter);
  $('file').addEventListener('change', () => loadFileInput($('file'), 'load'));
  $('load-editor').addEventListener('click', () => {
    const name = (pkmc.program && pkmc.program.name) || 'editor.ngc';
    send('load', { name, text: ed.value });
  });
  $('probe-list').addEventListener('click', (e) => {
    const li = e.target.closest('li');
    if (li) selectInEditor(Number(li.dataset.line), Number(li.dataset.col) || 0);
  });
  $('errors').addEventListener('click', (e) => {
    const li = e.target.closest('li');
    if (li) selectInEditor(Number(li.dataset.line), Number(li.dataset.col) || 0);
  });
  const ov = $('override');
  ov.addEventListener('pointerdown', () => { prog.overrideHeld = true; });
  window.addEventListener('pointerup', () => { prog.overrideHeld = false; });
  ov.addEventListener('input', () => {
    prog.overrideTouched = performance.now();
    setText($('override-set'), `${ov.value}%`);
  });
  ov.addEventListener('change', () => {
    prog.overrideTouched = performance.now();
    send('override', { percent: Number(ov.value) });
  });
  $('override-100').addEventListener('click', () => {
    ov.value = '100';
    prog.overrideTouched = performance.now();
    setText($('override-set'), '100%');
    send('override', { percent: 100 });
  });
  syncGutter();
}

// ================================================================= probing panel

/** A run of a program that probes: each probing move's result as it comes. */
function onProbes(m) {
  pkmc.probes = m;
  renderProbes();
}

/** Most MDI probing results the panel keeps. */
const MDI_PROBES = 50;

/** A probing move typed into MDI: the panel lists MDI's results (the last 50) until
 *  a program's run takes it over. Their lines are MDI's, not the editor's. */
function onMdiProbe(m) {
  const run = pkmc.probes;
  const before = run && run.program === 'MDI' ? run.records : [];
  pkmc.probes = { program: 'MDI', running: false, end: 'mdi', mdi: true,
    records: [...before, m.probe].slice(-MDI_PROBES) };
  renderProbes();
}

/** A length in mm to 4 decimals (0.1 µm), or 5 of an inch while inches are shown. */
function fmtProbe(v) {
  if (typeof v !== 'number' || !Number.isFinite(v)) return '—';
  const x = v / lengthScale();
  const d = units.inch ? 5 : 4;
  return Math.abs(x) < 0.5 * 10 ** -d ? (0).toFixed(d) : x.toFixed(d);
}

function xyzText(label, p) {
  return `${label.padEnd(7)} X ${fmtProbe(p[0])}  Y ${fmtProbe(p[1])}  Z ${fmtProbe(p[2])}`;
}

const PROBE_END = {
  done: 'the run ended: done', alarm: 'the run ended in an alarm',
  stopped: 'the run was stopped', paused: 'the run ended held at a pause',
  refused: 'the run stopped: the program cannot go on', failed: 'the run failed',
  mdi: 'typed into MDI',
};

/** The panel: shown for a program that probes, or after a run that probed. */
function renderProbes() {
  const program = pkmc.program;
  const run = pkmc.probes;
  const moves = (program && program.probing && program.probing.moves) || [];
  const records = (run && run.records) || [];
  $('probe-panel').classList.toggle('hidden', moves.length === 0 && records.length === 0);
  let note = '';
  if (moves.length > 0) {
    const lines = moves.slice(0, 8).map((m) => m.line).join(', ') + (moves.length > 8 ? ', …' : '');
    note = `${moves.length}${program.probing.capped ? '+' : ''} probing move(s), line ${lines}. ` +
      'The path and Check take each to its programmed end as if it touched there; ' +
      'Run probes a stage at a time and goes on from what the probe finds.';
  }
  setText($('probe-note'), note);
  const unit = units.inch ? 'in' : 'mm';
  const state = !run ? '' : run.running ? 'running' : (PROBE_END[run.end] || '');
  setText($('probe-info'), run && run.program ? `${run.program} · ${state}` : '');
  const items = records.map((r, i) => {
    const li = el('li', 'probe' + (r.contact ? '' : ' miss') + (i === records.length - 1 ? ' last' : ''));
    if (!run.mdi) li.dataset.line = String(r.line);
    const head = el('div', 'phead');
    head.appendChild(el('span', 'pline', run.mdi ? 'MDI' : `line ${r.line}`));
    head.appendChild(el('span', 'pcode', r.code));
    head.appendChild(el('span', 'pcontact ' + (r.contact ? 'yes' : 'no'),
      r.contact ? 'contact' : 'no contact'));
    li.appendChild(head);
    li.appendChild(el('div', 'pxyz probed', xyzText('probed', r.position) + ` ${unit}`));
    const pf = (run.program_frame || [])[i];
    if (pf) li.appendChild(el('div', 'pxyz program', xyzText('program', pf) + ` ${unit}`));
    li.appendChild(el('div', 'pxyz stopped', xyzText('stopped', r.stopped) + ` ${unit}`));
    return li;
  });
  if (run && run.refusal) {
    const f = run.refusal;
    const li = el('li', 'refusal', `line ${f.line}:${f.col}: ${f.message} — the program stopped there`);
    li.dataset.line = String(f.line);
    li.dataset.col = String(f.col);
    items.push(li);
  }
  const list = $('probe-list');
  list.replaceChildren(...items);
  // The newest in view (the list scrolls on its own, never the page).
  list.scrollTop = list.scrollHeight;
}

// ===================================================== jog, MDI and joint moves

const jog = { active: false, button: null };
const mdiHistory = { list: [], pos: 0 };

/** The jog feed in mm/min (the field is in in/min while inches are shown). */
function jogFeed() {
  const f = parseFloat($('jog-feed').value);
  return (f > 0 ? f : 600) * lengthScale();
}

/** The jog step for `axis` in mm or degrees: the chosen step, in inches on X Y Z
 *  while inches are shown, times `factor` (the keyboard's modifier). */
function jogDistance(axis, factor = 1) {
  const step = parseFloat($('jog-step').value) || 1;
  const linear = ['X', 'Y', 'Z'].includes(axis);
  return step * factor * (linear ? lengthScale() : 1);
}

function buildJogButtons(axes) {
  const box = $('jog-buttons');
  box.replaceChildren();
  for (const axis of axes) {
    for (const dir of [-1, 1]) {
      const b = el('button', 'jog', `${axis}${dir < 0 ? '−' : '+'}`);
      b.dataset.axis = axis;
      b.dataset.dir = String(dir);
      b.addEventListener('click', () => jogStep(b));
      b.addEventListener('pointerdown', (e) => jogStart(b, e));
      for (const ev of ['pointerup', 'pointerleave', 'pointercancel']) b.addEventListener(ev, jogStop);
      b.addEventListener('contextmenu', (e) => e.preventDefault());
      box.appendChild(b);
    }
  }
}

function jogStep(b) {
  if ($('jog-continuous').checked) return;
  send('jog', { axis: b.dataset.axis, distance: Number(b.dataset.dir) * jogDistance(b.dataset.axis), feed: jogFeed() });
}

function jogStart(b, e) {
  if (!$('jog-continuous').checked || e.button !== 0) return;
  e.preventDefault();
  if (jog.active) jogStop();
  jog.active = true;
  jog.button = b;
  b.classList.add('held');
  send('jog_start', { axis: b.dataset.axis, dir: Number(b.dataset.dir), feed: jogFeed() });
}

function jogStop() {
  if (!jog.active) return;
  jog.active = false;
  if (jog.button) jog.button.classList.remove('held');
  jog.button = null;
  send('jog_stop');
}

function buildJointSelect(joints) {
  const sel = $('joint-select');
  sel.replaceChildren(...joints.map((j, i) => {
    const o = el('option', '', j.name);
    o.value = String(i);
    return o;
  }));
  updateJointUnit();
}

function updateJointUnit() {
  const joints = (pkmc.machine && pkmc.machine.joints) || [];
  const j = joints[Number($('joint-select').value)];
  setText($('joint-unit'), j ? j.unit : '');
}

function jointMove(sign) {
  const d = parseFloat($('joint-distance').value);
  const joint = parseInt($('joint-select').value, 10);
  if (!Number.isFinite(d) || !Number.isInteger(joint)) {
    toast('joint move: choose a joint and a distance');
    return;
  }
  send('joint', { joint, distance: sign * Math.abs(d), feed: jogFeed() });
}

function sendMdi() {
  const input = $('mdi');
  const text = input.value.trim();
  if (!text) return;
  send('mdi', { text });
  const h = mdiHistory.list;
  if (h[h.length - 1] !== text) h.push(text);
  if (h.length > 50) h.shift();
  mdiHistory.pos = h.length;
  input.value = '';
}

function mdiKey(e) {
  const h = mdiHistory.list;
  if (e.key === 'Enter') {
    e.preventDefault();
    sendMdi();
  } else if (e.key === 'ArrowUp' && h.length) {
    e.preventDefault();
    mdiHistory.pos = Math.max(0, mdiHistory.pos - 1);
    $('mdi').value = h[mdiHistory.pos];
  } else if (e.key === 'ArrowDown' && h.length) {
    e.preventDefault();
    mdiHistory.pos = Math.min(h.length, mdiHistory.pos + 1);
    $('mdi').value = h[mdiHistory.pos] ?? '';
  }
}

function initJogPanel() {
  window.addEventListener('blur', jogStop);
  window.addEventListener('pointerup', jogStop);
  document.addEventListener('visibilitychange', () => { if (document.hidden) jogStop(); });
  $('jog-continuous').addEventListener('change', jogStop);
  $('mdi').addEventListener('keydown', mdiKey);
  $('mdi-send').addEventListener('click', sendMdi);
  $('joint-select').addEventListener('change', updateJointUnit);
  $('joint-minus').addEventListener('click', () => jointMove(-1));
  $('joint-plus').addEventListener('click', () => jointMove(1));
}

// ==================================================================== teach list

function onTeach(t) {
  pkmc.teach = t;
  const points = t.points || [];
  const items = points.map((p, i) => {
    const li = el('li', i === t.next ? 'next' : '');
    li.dataset.index = String(i);
    li.appendChild(el('span', 'tname', p.name || `P${i + 1}`));
    li.appendChild(el('span', 'tpose num', (p.pose || []).map(fmt3).join(' ')));
    const tools = el('span', 'tools');
    tools.appendChild(el('button', 'up small', '▲'));
    tools.appendChild(el('button', 'down small', '▼'));
    tools.appendChild(el('button', 'remove small', '✕'));
    li.appendChild(tools);
    return li;
  });
  $('teach-list').replaceChildren(...items);
  const speed = $('teach-speed');
  if (typeof t.speed === 'number' && document.activeElement !== speed) speed.value = String(t.speed);
}

function onTeachListClick(e) {
  const b = e.target.closest('button');
  const li = e.target.closest('li');
  if (!b || !li) return;
  const index = Number(li.dataset.index);
  const n = $('teach-list').childElementCount;
  if (b.classList.contains('up') && index > 0) send('teach_move', { index, to: index - 1 });
  else if (b.classList.contains('down') && index < n - 1) send('teach_move', { index, to: index + 1 });
  else if (b.classList.contains('remove')) send('teach_remove', { index });
}

function initTeachPanel() {
  $('teach-list').addEventListener('click', onTeachListClick);
  $('teach-speed').addEventListener('change', () => {
    const speed = parseFloat($('teach-speed').value);
    if (speed > 0) send('teach_speed', { speed });
  });
  $('teach-load').addEventListener('change', () => loadFileInput($('teach-load'), 'teach_load'));
}

// ================================================================ log and toast

const LOG_KEEP = 200;
let toastTimer = null;

function addLog(level, text) {
  const lv = ['info', 'warn', 'error'].includes(level) ? level : 'info';
  const now = new Date();
  pkmc.log.push({ level: lv, text, time: now.getTime() });
  if (pkmc.log.length > LOG_KEEP) pkmc.log.shift();
  const box = $('log');
  const atBottom = box.scrollTop + box.clientHeight >= box.scrollHeight - 4;
  const div = el('div', lv);
  div.appendChild(el('time', '', now.toTimeString().slice(0, 8)));
  div.appendChild(document.createTextNode(' ' + text));
  box.appendChild(div);
  while (box.childElementCount > LOG_KEEP) box.firstChild.remove();
  if (atBottom) box.scrollTop = box.scrollHeight;
}

function toast(text) {
  const t = $('toast');
  t.textContent = text;
  t.classList.add('show');
  clearTimeout(toastTimer);
  toastTimer = setTimeout(() => t.classList.remove('show'), 3500);
}

// ======================================================================= 3-D view

// Line style of each scene KIND: colour, width (CSS px), dash.
const SEG_STYLE = {
  frame: ['#3b4858', 1.5], base: ['#6f7d8c', 3], rail: ['#8796a6', 3],
  carriage: ['#ffab2e', 8], forearm: ['#48b0ff', 2.2], bar: ['#a9d6ff', 4],
  leg: ['#48b0ff', 3], platform: ['#a9d6ff', 3], table: ['#9fb0c3', 2],
  axis: ['#ffd34d', 1.2, [6, 4]], tool: ['#ff5a5a', 3.5],
};
const SEG_ORDER = Object.keys(SEG_STYLE);
const POLY_FILL = {
  table: 'rgba(150,170,195,0.22)', platform: 'rgba(72,176,255,0.20)',
  base: 'rgba(110,125,140,0.20)', frame: 'rgba(80,95,115,0.15)',
};
const PATH_DRAW_MAX = 20000;
const CUT_MAX = 200000;
const CUT_DRAW_MAX = 40000;
const VIEWS = {
  top: { yaw: 0, pitch: Math.PI / 2 },
  front: { yaw: 0, pitch: 0 },
  side: { yaw: Math.PI / 2, pitch: 0 },
  '3d': { yaw: Math.PI / 6, pitch: 0.5 },
};

const view = {
  canvas: null, ctx: null, w: 0, h: 0, dpr: 1, bg: null,
  mode: '3d', yaw: VIEWS['3d'].yaw, pitch: VIEWS['3d'].pitch, scale: 1, target: [0, 0, 0],
  r: [1, 0, 0], u: [0, 0, 1], f: [0, 1, 0],
  bounds: { min: [-500, -500, -300], max: [500, 500, 700] }, fitted: false,
  scene: null, progFeed: null, progRapid: null, drag: null,
  setBounds, setProgramPath,
};

// The camera: right r, up u and forward f (into the screen) from yaw about Z and
// pitch (elevation) — yaw 0, pitch 0 looks along +Y with X right and Z up.
function updateBasis() {
  const cy = Math.cos(view.yaw), sy = Math.sin(view.yaw);
  const cp = Math.cos(view.pitch), sp = Math.sin(view.pitch);
  view.r = [cy, sy, 0];
  view.f = [-sy * cp, cy * cp, -sp];
  view.u = [-sy * sp, cy * sp, cp];
}

const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];

/** The affine map machine point → screen px, as [ax,ay,az,bx, cx,cy,cz,by]. */
function screenAffine() {
  const s = view.scale, r = view.r, u = view.u, T = view.target;
  return [s * r[0], s * r[1], s * r[2], view.w / 2 - s * dot(T, r),
    -s * u[0], -s * u[1], -s * u[2], view.h / 2 + s * dot(T, u)];
}

/** Composes the screen map with the row-major 3x4 work matrix W. */
function withWork(A, W) {
  if (!W || W.length < 12) return A;
  const out = new Array(8);
  for (let row = 0; row < 2; row++) {
    const o = row * 4;
    for (let j = 0; j < 4; j++) {
      out[o + j] = A[o] * W[j] + A[o + 1] * W[4 + j] + A[o + 2] * W[8 + j];
    }
    out[o + 3] += A[o + 3];
  }
  return out;
}

function setBounds(b) {
  if (b && b.min && b.max) view.bounds = { min: b.min.slice(0, 3), max: b.max.slice(0, 3) };
  fitView();
}

/** Centres the bounds box and scales it to fill the canvas. */
function fitView() {
  fitBox(view.bounds.min, view.bounds.max, null);
}

/** Centres the program's path (workpiece coordinates, placed by the scene's work
 *  matrix) and scales it to fill the canvas. */
function fitProgram() {
  const b = view.progBox;
  if (!b) { toast('no program path to fit'); return; }
  // Room around a path that is a point or a line.
  const pad = [0, 1, 2].map((k) => Math.max(1, 0.05 * (b.max[k] - b.min[k])));
  fitBox(b.min.map((v, k) => v - pad[k]), b.max.map((v, k) => v + pad[k]),
    view.scene && view.scene.work);
}

/** Where the program's path lies on the canvas now: its box in CSS px and the
 *  canvas' size (for the tests: how much of the view the program fills). */
function programExtent() {
  const A = withWork(screenAffine(), view.scene && view.scene.work);
  const pts = [view.progFeed, view.progRapid];
  let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
  for (const a of pts) {
    for (let i = 0; a && i < a.length; i += 3) {
      if (Number.isNaN(a[i])) continue;
      const x = A[0] * a[i] + A[1] * a[i + 1] + A[2] * a[i + 2] + A[3];
      const y = A[4] * a[i] + A[5] * a[i + 1] + A[6] * a[i + 2] + A[7];
      x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y);
    }
  }
  return { left: x0, right: x1, top: y0, bottom: y1, w: view.w, h: view.h };
}
pkmc.programExtent = programExtent;

/** Fits the box [min, max] (mapped by the row-major 3x4 matrix W, if any). */
function fitBox(min, max, W) {
  const map = (p) => (W && W.length >= 12 ? [0, 1, 2].map((r) =>
    W[4 * r] * p[0] + W[4 * r + 1] * p[1] + W[4 * r + 2] * p[2] + W[4 * r + 3]) : p);
  let r0 = Infinity, r1 = -Infinity, u0 = Infinity, u1 = -Infinity;
  const c0 = [Infinity, Infinity, Infinity], c1 = [-Infinity, -Infinity, -Infinity];
  for (let k = 0; k < 8; k++) {
    const p = map([k & 1 ? max[0] : min[0], k & 2 ? max[1] : min[1], k & 4 ? max[2] : min[2]]);
    const pr = dot(p, view.r), pu = dot(p, view.u);
    r0 = Math.min(r0, pr); r1 = Math.max(r1, pr);
    u0 = Math.min(u0, pu); u1 = Math.max(u1, pu);
    for (let i = 0; i < 3; i++) { c0[i] = Math.min(c0[i], p[i]); c1[i] = Math.max(c1[i], p[i]); }
  }
  view.target = [0, 1, 2].map((i) => (c0[i] + c1[i]) / 2);
  const w = Math.max(view.w - 20, 50), h = Math.max(view.h - 80, 50); // room for the overlays
  view.scale = Math.min(w / Math.max(r1 - r0, 1e-3), h / Math.max(u1 - u0, 1e-3)) * 0.95;
  view.fitted = view.w > 0;
}

function setViewMode(mode) {
  view.mode = mode;
  view.yaw = VIEWS[mode].yaw;
  view.pitch = VIEWS[mode].pitch;
  updateBasis();
  fitView();
  for (const m of Object.keys(VIEWS)) $('view-' + m).classList.toggle('active', m === mode);
  setText($('view-hint'), mode === '3d'
    ? 'drag: rotate · shift/right-drag: pan · wheel: zoom'
    : 'drag: pan · wheel: zoom');
}

/** Splits the program path into feed and rapid polylines (NaN = pen up), ≤20k points;
 *  the points on lines with an error are kept apart, to be marked. */
function setProgramPath(path, errLines = []) {
  const bad = new Set(errLines);
  const errs = [];
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (const p of path) {
    if (bad.has(p[3])) errs.push(p[0], p[1], p[2]);
    for (let k = 0; k < 3; k++) { lo[k] = Math.min(lo[k], p[k]); hi[k] = Math.max(hi[k], p[k]); }
  }
  view.progErr = Float32Array.from(errs);
  view.progBox = path.length ? { min: lo, max: hi } : null;
  const n = path.length;
  const stride = Math.max(1, Math.ceil(n / PATH_DRAW_MAX));
  const keep = (i) => i % stride === 0 || i === n - 1 ||
    (i > 0 && path[i][4] !== path[i - 1][4]) || (i < n - 1 && path[i][4] !== path[i + 1][4]);
  const feed = [], rapid = [];
  let prev = null, prevRapid = null;
  for (let i = 0; i < n; i++) {
    if (!keep(i)) continue;
    const p = path[i];
    if (prev) {
      const isRapid = !!p[4];
      const arr = isRapid ? rapid : feed;
      if (prevRapid !== isRapid) {
        if (arr.length) arr.push(NaN, NaN, NaN);
        arr.push(prev[0], prev[1], prev[2]);
      }
      arr.push(p[0], p[1], p[2]);
      prevRapid = isRapid;
    }
    prev = p;
  }
  view.progFeed = Float32Array.from(feed);
  view.progRapid = Float32Array.from(rapid);
  pkmc.preview = { points: n, errors: errs.length / 3, box: view.progBox };
}

// ----- the cut path: the pose while a job runs, in workpiece coordinates

const cut = { buf: new Float32Array(3 * 8192), n: 0, pen: false, last: [NaN, NaN, NaN] };

function recordCut(st) {
  const active = st.state === 'Running' || st.job != null;
  if (!active || !st.pose) {
    cut.pen = false;
    return;
  }
  const [x, y, z] = st.pose;
  const l = cut.last;
  if (cut.pen && Math.abs(x - l[0]) + Math.abs(y - l[1]) + Math.abs(z - l[2]) < 0.005) return;
  if (!cut.pen && cut.n > 0) pushCut(NaN, NaN, NaN);
  pushCut(x, y, z);
  cut.last = [x, y, z];
  cut.pen = true;
}

function pushCut(x, y, z) {
  if (cut.n >= CUT_MAX) decimateCut();
  if (3 * (cut.n + 1) > cut.buf.length) {
    const bigger = new Float32Array(Math.min(cut.buf.length * 2, 3 * CUT_MAX));
    bigger.set(cut.buf);
    cut.buf = bigger;
  }
  const o = 3 * cut.n++;
  cut.buf[o] = x;
  cut.buf[o + 1] = y;
  cut.buf[o + 2] = z;
}

/** Halves the cut path: every second point goes, pen-up markers and the last point stay. */
function decimateCut() {
  const b = cut.buf;
  let w = 0;
  for (let i = 0; i < cut.n; i++) {
    const o = 3 * i;
    if (i % 2 === 0 || b[o] !== b[o] || i === cut.n - 1) {
      b[3 * w] = b[o]; b[3 * w + 1] = b[o + 1]; b[3 * w + 2] = b[o + 2];
      w++;
    }
  }
  cut.n = w;
}

function clearCut() {
  cut.n = 0;
  cut.pen = false;
}

// ----- drawing

/** Strokes a NaN-separated polyline of n points through the affine map M. */
function tracePolyline(ctx, arr, n, M, maxPoints) {
  const stride = Math.max(1, Math.ceil(n / maxPoints));
  let pen = false;
  for (let i = 0; i < n; i++) {
    const o = 3 * i;
    const x = arr[o];
    if (x !== x) { pen = false; continue; }
    if (pen && i % stride !== 0 && i !== n - 1 && arr[o + 3] === arr[o + 3]) continue;
    const y = arr[o + 1], z = arr[o + 2];
    const sx = M[0] * x + M[1] * y + M[2] * z + M[3];
    const sy = M[4] * x + M[5] * y + M[6] * z + M[7];
    if (pen) ctx.lineTo(sx, sy);
    else { ctx.moveTo(sx, sy); pen = true; }
  }
}

function niceStep(span) {
  const raw = span / 10;
  const p = Math.pow(10, Math.floor(Math.log10(raw)));
  return [1, 2, 5, 10].map((k) => k * p).find((s) => s >= raw) || 10 * p;
}

function drawGrid(ctx, A) {
  const { min, max } = view.bounds;
  const step = niceStep(Math.max(max[0] - min[0], max[1] - min[1]));
  const z = min[2];
  const x0 = Math.floor(min[0] / step) * step, x1 = Math.ceil(max[0] / step) * step;
  const y0 = Math.floor(min[1] / step) * step, y1 = Math.ceil(max[1] / step) * step;
  const P = (x, y) => [A[0] * x + A[1] * y + A[2] * z + A[3], A[4] * x + A[5] * y + A[6] * z + A[7]];
  ctx.beginPath();
  for (let x = x0; x <= x1 + 1e-6; x += step) { ctx.moveTo(...P(x, y0)); ctx.lineTo(...P(x, y1)); }
  for (let y = y0; y <= y1 + 1e-6; y += step) { ctx.moveTo(...P(x0, y)); ctx.lineTo(...P(x1, y)); }
  ctx.strokeStyle = '#1c2631';
  ctx.lineWidth = 1;
  ctx.stroke();
}

function drawPolys(ctx, A, polys) {
  const f = view.f;
  const items = polys.map(([kind, pts]) => {
    let depth = 0;
    for (const p of pts) depth += dot(p, f);
    return { kind, pts, depth: depth / Math.max(pts.length, 1) };
  }).sort((a, b) => b.depth - a.depth);
  ctx.lineWidth = 1.2;
  for (const { kind, pts } of items) {
    if (pts.length < 2) continue;
    ctx.beginPath();
    pts.forEach((p, i) => {
      const sx = A[0] * p[0] + A[1] * p[1] + A[2] * p[2] + A[3];
      const sy = A[4] * p[0] + A[5] * p[1] + A[6] * p[2] + A[7];
      if (i) ctx.lineTo(sx, sy); else ctx.moveTo(sx, sy);
    });
    ctx.closePath();
    ctx.fillStyle = POLY_FILL[kind] || 'rgba(140,150,165,0.18)';
    ctx.fill();
    ctx.strokeStyle = (SEG_STYLE[kind] || SEG_STYLE.frame)[0];
    ctx.stroke();
  }
}

function drawSegs(ctx, A, segs, kinds) {
  ctx.lineCap = 'round';
  for (const kind of kinds) {
    const [color, width, dash] = SEG_STYLE[kind];
    ctx.beginPath();
    let any = false;
    for (const s of segs) {
      if (s[6] !== kind) continue;
      ctx.moveTo(A[0] * s[0] + A[1] * s[1] + A[2] * s[2] + A[3], A[4] * s[0] + A[5] * s[1] + A[6] * s[2] + A[7]);
      ctx.lineTo(A[0] * s[3] + A[1] * s[4] + A[2] * s[5] + A[3], A[4] * s[3] + A[5] * s[4] + A[6] * s[5] + A[7]);
      any = true;
    }
    if (!any) continue;
    ctx.setLineDash(dash || []);
    ctx.strokeStyle = color;
    ctx.lineWidth = width;
    ctx.stroke();
  }
  ctx.setLineDash([]);
  ctx.lineCap = 'butt';
}

function drawPaths(ctx, M) {
  if (view.progRapid && view.progRapid.length) {
    ctx.beginPath();
    tracePolyline(ctx, view.progRapid, view.progRapid.length / 3, M, PATH_DRAW_MAX);
    ctx.setLineDash([4, 4]);
    ctx.strokeStyle = 'rgba(200,210,225,0.35)';
    ctx.lineWidth = 1;
    ctx.stroke();
    ctx.setLineDash([]);
  }
  if (view.progFeed && view.progFeed.length) {
    ctx.beginPath();
    tracePolyline(ctx, view.progFeed, view.progFeed.length / 3, M, PATH_DRAW_MAX);
    ctx.strokeStyle = 'rgba(45,212,191,0.85)';
    ctx.lineWidth = 1.2;
    ctx.stroke();
  }
  const e = view.progErr;
  if (e && e.length) {
    ctx.strokeStyle = '#ff4d4f';
    ctx.lineWidth = 2;
    for (let i = 0; i < e.length && i < 3 * 2000; i += 3) {
      const sx = M[0] * e[i] + M[1] * e[i + 1] + M[2] * e[i + 2] + M[3];
      const sy = M[4] * e[i] + M[5] * e[i + 1] + M[6] * e[i + 2] + M[7];
      ctx.beginPath();
      ctx.moveTo(sx - 5, sy - 5); ctx.lineTo(sx + 5, sy + 5);
      ctx.moveTo(sx - 5, sy + 5); ctx.lineTo(sx + 5, sy - 5);
      ctx.stroke();
    }
  }
  if (cut.n > 1) {
    ctx.beginPath();
    tracePolyline(ctx, cut.buf, cut.n, M, CUT_DRAW_MAX);
    ctx.strokeStyle = '#ffe14d';
    ctx.lineWidth = 2.2;
    ctx.stroke();
  }
}

function drawToolTip(ctx, M, pose) {
  if (!pose) return;
  const sx = M[0] * pose[0] + M[1] * pose[1] + M[2] * pose[2] + M[3];
  const sy = M[4] * pose[0] + M[5] * pose[1] + M[6] * pose[2] + M[7];
  ctx.beginPath();
  ctx.arc(sx, sy, 6, 0, 2 * Math.PI);
  ctx.fillStyle = 'rgba(255,61,242,0.25)';
  ctx.fill();
  ctx.strokeStyle = '#ff3df2';
  ctx.lineWidth = 1.5;
  ctx.stroke();
  ctx.beginPath();
  ctx.moveTo(sx - 10, sy); ctx.lineTo(sx + 10, sy);
  ctx.moveTo(sx, sy - 10); ctx.lineTo(sx, sy + 10);
  ctx.stroke();
}

/** The workpiece origin's axes, len mm long (through `work`): shows the table's tilt. */
function drawWorkAxes(ctx, M, len) {
  const o = [M[3], M[7]];
  const colors = ['#ff5c5c', '#4cd964', '#4c8dff'];
  ctx.lineWidth = 1.5;
  for (let k = 0; k < 3; k++) {
    ctx.beginPath();
    ctx.moveTo(o[0], o[1]);
    ctx.lineTo(o[0] + M[k] * len, o[1] + M[4 + k] * len);
    ctx.strokeStyle = colors[k];
    ctx.stroke();
  }
}

/** The machine axes triad in the lower left corner. */
function drawTriad(ctx) {
  const cx = 42, cy = view.h - 42, L = 26;
  const names = ['X', 'Y', 'Z'];
  const colors = ['#ff5c5c', '#4cd964', '#4c8dff'];
  ctx.font = '11px system-ui, sans-serif';
  ctx.textAlign = 'center';
  ctx.textBaseline = 'middle';
  ctx.lineWidth = 2;
  for (let k = 0; k < 3; k++) {
    const dx = view.r[k] * L, dy = -view.u[k] * L;
    ctx.beginPath();
    ctx.moveTo(cx, cy);
    ctx.lineTo(cx + dx, cy + dy);
    ctx.strokeStyle = colors[k];
    ctx.stroke();
    if (Math.hypot(dx, dy) > 4) {
      ctx.fillStyle = colors[k];
      ctx.fillText(names[k], cx + dx * 1.35, cy + dy * 1.35);
    }
  }
}

function drawScene() {
  const ctx = view.ctx;
  ctx.setTransform(view.dpr, 0, 0, view.dpr, 0, 0);
  ctx.fillStyle = view.bg || '#0d1117';
  ctx.fillRect(0, 0, view.w, view.h);
  const A = screenAffine();
  drawGrid(ctx, A);
  const scene = view.scene || {};
  const M = withWork(A, scene.work);
  if (scene.polys) drawPolys(ctx, A, scene.polys);
  const segs = scene.segs || [];
  drawSegs(ctx, A, segs, SEG_ORDER.filter((k) => k !== 'tool'));
  drawWorkAxes(ctx, M, 40);
  drawPaths(ctx, M);
  drawSegs(ctx, A, segs, ['tool']);
  drawToolTip(ctx, M, pkmc.lastStatus && pkmc.lastStatus.pose);
  drawTriad(ctx);
}

// ----- canvas size, render loop and the readout

function resizeCanvas() {
  const c = view.canvas;
  const rect = c.getBoundingClientRect();
  view.dpr = window.devicePixelRatio || 1;
  view.w = Math.max(1, rect.width);
  view.h = Math.max(1, rect.height);
  c.width = Math.round(view.w * view.dpr);
  c.height = Math.round(view.h * view.dpr);
  const g = view.ctx.createLinearGradient(0, 0, 0, view.h);
  g.addColorStop(0, '#131a22');
  g.addColorStop(1, '#07090c');
  view.bg = g;
  if (!view.fitted) fitView();
}

const loop = { prev: null, lastReadout: 0, drawMs: 0, failed: false };

function frame() {
  const now = performance.now();
  if (loop.prev !== null) pushCapped(pkmc.stats.frames, now - loop.prev);
  loop.prev = now;
  try {
    drawScene();
  } catch (e) {
    if (!loop.failed) addLog('error', `drawing failed: ${e.message}`);
    loop.failed = true;
  }
  const drawn = performance.now() - now;
  pushCapped(pkmc.stats.draw, drawn);
  loop.drawMs = 0.9 * loop.drawMs + 0.1 * drawn;
  if (now - loop.lastReadout > 500) {
    loop.lastReadout = now;
    updateReadout(now);
  }
  requestAnimationFrame(frame);
}

function updateReadout(now) {
  const fr = pkmc.stats.frames;
  let t = 0, n = 0;
  for (let i = fr.length - 1; i >= 0 && t < 1000; i--, n++) t += fr[i];
  const fps = t > 0 ? (1000 * n) / t : 0;
  const st = pkmc.stats.status;
  let k = 0;
  for (let i = st.length - 1; i >= 0 && st[i] > now - 1000; i--) k++;
  setText($('fps'), `${fps.toFixed(0)} fps · status ${k} Hz · draw ${loop.drawMs.toFixed(1)} ms`);
}

// ----- mouse: orbit, pan, zoom

function onPointerDown(e) {
  view.drag = { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.button === 1 || e.shiftKey };
  view.canvas.setPointerCapture(e.pointerId);
  e.preventDefault();
}

function onPointerMove(e) {
  const d = view.drag;
  if (!d) return;
  const dx = e.clientX - d.x, dy = e.clientY - d.y;
  d.x = e.clientX;
  d.y = e.clientY;
  if (d.pan || e.shiftKey || view.mode !== '3d') {
    const s = view.scale;
    view.target = view.target.map((t, i) => t - (view.r[i] * dx) / s + (view.u[i] * dy) / s);
  } else {
    view.yaw -= dx * 0.008;
    view.pitch = Math.max(-Math.PI / 2, Math.min(Math.PI / 2, view.pitch + dy * 0.008));
    updateBasis();
  }
}

function onWheel(e) {
  e.preventDefault();
  const rect = view.canvas.getBoundingClientRect();
  const mx = e.clientX - rect.left - view.w / 2, my = view.h / 2 - (e.clientY - rect.top);
  const s1 = view.scale;
  const s2 = Math.max(1e-4, Math.min(1e4, s1 * Math.exp(-e.deltaY * 0.0015)));
  const a = mx / s1 - mx / s2, b = my / s1 - my / s2;
  view.target = view.target.map((t, i) => t + view.r[i] * a + view.u[i] * b);
  view.scale = s2;
}

function initView() {
  view.canvas = $('scene');
  view.ctx = view.canvas.getContext('2d');
  updateBasis();
  const c = view.canvas;
  c.addEventListener('pointerdown', onPointerDown);
  c.addEventListener('pointermove', onPointerMove);
  const end = () => { view.drag = null; };
  c.addEventListener('pointerup', end);
  c.addEventListener('pointercancel', end);
  c.addEventListener('wheel', onWheel, { passive: false });
  c.addEventListener('contextmenu', (e) => e.preventDefault());
  c.addEventListener('dblclick', fitView);
  for (const m of Object.keys(VIEWS)) $('view-' + m).addEventListener('click', () => setViewMode(m));
  $('view-fit').addEventListener('click', fitView);
  $('view-fit-prog').addEventListener('click', fitProgram);
  $('clear-path').addEventListener('click', clearCut);
  new ResizeObserver(resizeCanvas).observe($('view'));
  resizeCanvas();
  requestAnimationFrame(frame);
}

// ================================================= units and the keyboard jog

const units = { inch: false };

/** mm per shown length unit: 25.4 while inches are shown. */
function lengthScale() {
  return units.inch ? 25.4 : 1;
}

/** A length in mm, shown in the display's unit (3 decimals of mm, 4 of an inch). */
function fmtLen(v) {
  if (!units.inch) return fmt3(v);
  if (typeof v !== 'number' || !Number.isFinite(v)) return '—';
  const x = v / 25.4;
  return Math.abs(x) < 0.00005 ? '0.0000' : x.toFixed(4);
}

/** Switches the lengths shown (DRO, joints in mm, feeds, jog step and feed) between
 *  millimetres and inches. The controller is always spoken to in mm. */
function setInch(inch) {
  units.inch = inch;
  const u = inch ? 'in' : 'mm';
  document.querySelectorAll('#dro .dro-row').forEach((row) => {
    if (['X', 'Y', 'Z'].includes(row.dataset.axis)) setText(row.querySelector('.unit'), u);
  });
  setText($('feed').nextElementSibling, `${u}/min`);
  setText($('jog-feed').nextElementSibling, `${u}/min`);
  dro.joints.forEach((j) => { if (j.linear) setText(j.unit, u); j.pct = -1; });
  setText($('units'), inch ? 'mm' : 'in');
  $('units').title = inch ? 'Show lengths in millimetres' : 'Show lengths in inches';
  pkmc.units = u;
  if (pkmc.lastStatus) { updateDro(pkmc.lastStatus); updateJoints(pkmc.lastStatus); }
  renderProbes();
}

/** The keyboard jog: arrows X and Y, Page Up and Page Down Z, by the chosen step;
 *  Shift ten times it, Alt a tenth. Not while typing in a field. */
const JOG_KEYS = {
  ArrowLeft: ['X', -1], ArrowRight: ['X', 1], ArrowDown: ['Y', -1], ArrowUp: ['Y', 1],
  PageDown: ['Z', -1], PageUp: ['Z', 1],
};

function onJogKey(e) {
  const k = JOG_KEYS[e.key];
  if (!k || e.ctrlKey || e.metaKey) return;
  const t = e.target;
  if (t && (t.isContentEditable || ['INPUT', 'TEXTAREA', 'SELECT'].includes(t.tagName))) return;
  e.preventDefault();
  if (e.repeat) return;
  const axes = (pkmc.machine && pkmc.machine.axes) || AXES;
  if (!axes.includes(k[0])) return;
  if (!pkmc.jogEnabled) {
    toast('jog: not now (the machine is in alarm, homing or running a job)');
    return;
  }
  const factor = e.shiftKey ? 10 : e.altKey ? 0.1 : 1;
  const distance = k[1] * jogDistance(k[0], factor);
  pkmc.lastKeyJog = { axis: k[0], distance };
  send('jog', { axis: k[0], distance, feed: jogFeed() });
}

function initAids() {
  $('units').addEventListener('click', (e) => { e.stopPropagation(); setInch(!units.inch); });
  document.addEventListener('keydown', onJogKey);
}

// ====================================================================== start-up

function initCommandButtons() {
  document.querySelectorAll('button[data-cmd]').forEach((b) => {
    b.addEventListener('click', () => {
      if (b.dataset.cmd === 'release') conn.userReleased = true;
      if (b.dataset.cmd === 'take') conn.userReleased = false;
      send(b.dataset.cmd);
    });
  });
}

function init() {
  setConnected(false);
  initCommandButtons();
  initProgramPanel();
  initJogPanel();
  initTeachPanel();
  initAids();
  initView();
  connect();
}

init();
})();
