// pkmc operator station: the Tune panel. Plain ES2020, no libraries. The tune runs
// on the server (`nc-send tune`'s own code, on the station's link); this script sends
// the panel's fields, shows the result the server sends to every page (`tune`), its
// plot (the SVG `nc-send tune --plot` draws) and the refusals, and asks for Write
// gains only when that button is pressed.
'use strict';
(() => {

const $ = (id) => document.getElementById(id);
const pkmc = window.pkmc;

const tune = pkmc.tune = {
  state: null, // the last `tune` message
  ids: new Set(), // this panel's command ids
  asked: null, // the command in flight: 'tune' or 'tune_write'
};

/** A number field: its value, or null when empty. */
function optional(id) {
  const v = $(id).value.trim();
  return v === '' ? null : Number(v);
}

function command(cmd, args = {}) {
  const id = pkmc.send(cmd, args);
  if (id !== null) {
    tune.ids.add(id);
    tune.asked = cmd;
  }
  return id;
}

function fmt(v, digits = 4) {
  if (v === null || v === undefined) return '—';
  if (v === 0) return '0';
  return Math.abs(v) >= 0.01 && Math.abs(v) < 1e5 ? v.toPrecision(digits) : v.toExponential(digits - 1);
}

function row(cells, head = false) {
  const tr = document.createElement('tr');
  for (const c of cells) {
    const td = document.createElement(head ? 'th' : 'td');
    td.textContent = c;
    tr.appendChild(td);
  }
  return tr;
}

/** The result: fit, step, gains present and designed, margins. */
function renderResult(r) {
  const box = $('tune-result');
  box.textContent = '';
  if (!r) return;
  const head = document.createElement('p');
  head.textContent = `${r.name} (joint ${r.joint}): test signal ±${fmt(r.amplitude)} ${r.unit}` +
    ` · fit ${r.fit_percent.toFixed(1)} % · model vs measured step ${(100 * r.step_error).toFixed(2)} %`;
  box.appendChild(head);
  const t = document.createElement('table');
  t.id = 'tune-gains';
  t.appendChild(row(['', 'kp', 'ki', 'kd', 'kvff', 'kaff', 'crossover rad/s', 'PM °', 'GM dB', 'stable'], true));
  for (const which of ['present', 'designed']) {
    const g = r[which];
    const m = r.margins[which];
    const tr = row([which, fmt(g.kp), fmt(g.ki), fmt(g.kd), fmt(g.kvff), fmt(g.kaff),
      fmt(m.crossover_rad_s), m.phase_margin_deg.toFixed(1),
      m.gain_margin_db === null ? '∞' : m.gain_margin_db.toFixed(1), m.stable ? 'yes' : 'NO']);
    tr.dataset.which = which;
    t.appendChild(tr);
  }
  box.appendChild(t);
  const aimed = document.createElement('p');
  aimed.textContent = `aimed at: crossover ${fmt(r.aimed.crossover_rad_s)} rad/s, PM ${r.aimed.phase_margin_deg.toFixed(0)}°`;
  box.appendChild(aimed);
  if (r.lqg) {
    const l = document.createElement('p');
    l.textContent = `LQG on the model (Write gains writes the designed weights, their gains and the model): ${r.lqg}`;
    box.appendChild(l);
  }
  const line = document.createElement('p');
  line.id = 'tune-line';
  line.textContent = `Write gains writes: ${r.line}`;
  box.appendChild(line);
}

function renderPlot(r) {
  const box = $('tune-plot');
  box.innerHTML = r ? r.svg : '';
  const svg = box.querySelector('svg');
  if (!svg) return;
  // Scaled to the panel: the drawing's own size becomes its view box.
  const w = svg.getAttribute('width');
  const h = svg.getAttribute('height');
  if (w && h && !svg.getAttribute('viewBox')) svg.setAttribute('viewBox', `0 0 ${w} ${h}`);
  svg.removeAttribute('width');
  svg.removeAttribute('height');
}

function onTune(m) {
  const before = tune.state;
  tune.state = m;
  $('tune-info').textContent = m.running ? `tuning ${m.running}…` : (m.result ? `${m.result.name} tuned` : '');
  $('tune-error').textContent = m.error ? `Tune: ${m.error}` : '';
  $('tune-written').textContent = m.written || '';
  if (!before || before.result !== m.result) {
    renderResult(m.result);
    renderPlot(m.result);
    $('tune-report').textContent = m.result ? m.result.report.join('\n') : '';
  }
  $('tune-write').disabled = !m.result || !!m.running;
  $('tune-run').classList.toggle('active', !!m.running);
}

/** Replies to this panel's commands: a refusal is shown on the panel. */
function onReply(r) {
  if (!tune.ids.has(r.id)) return;
  tune.ids.delete(r.id);
  tune.asked = null;
  if (!r.ok) $('tune-error').textContent = `Tune: ${r.text}`;
}

const appReply = pkmc.handlers.reply;
pkmc.handlers.reply = (r) => {
  onReply(r);
  appReply(r);
};
const appHello = pkmc.handlers.hello;
pkmc.handlers.hello = (m) => {
  appHello(m);
  const sel = $('tune-joint');
  sel.textContent = '';
  for (const j of (m.machine && m.machine.joints) || []) {
    if (!j.servo) continue;
    const o = document.createElement('option');
    o.value = j.name;
    o.textContent = j.name;
    sel.appendChild(o);
  }
  if (!sel.options.length) {
    $('tune-info').textContent = 'no servo joint';
    $('tune-run').disabled = true;
  }
};
pkmc.handlers.tune = onTune;

function init() {
  $('tune-run').addEventListener('click', () => {
    $('tune-error').textContent = '';
    command('tune', {
      joint: $('tune-joint').value,
      amplitude: optional('tune-amplitude'),
      bandwidth: optional('tune-bandwidth'),
      phase_margin: optional('tune-pm'),
    });
  });
  $('tune-write').addEventListener('click', () => {
    $('tune-error').textContent = '';
    command('tune_write');
  });
}

init();
})();
