#!/usr/bin/env node
/*
 * Runs one G-code job through a real CNCjs 1.11.5 server against a Grbl 1.1
 * serial device (for us: the bridge's pseudo-terminal), and prints ONE JSON
 * object on stdout describing what CNCjs saw.
 *
 *   node cncjs_job.js --port /dev/pts/N --program FILE
 *        [--hold-at SECONDS --resume-at SECONDS] [--hold-command feedhold|pause]
 *        [--feed-override-at SECONDS:PERCENT]... [--timeout SECONDS]
 *        [--ready-timeout SECONDS] [--baudrate N] [--verbose] [--keep-tmp]
 *
 * Times given to --hold-at/--resume-at/--feed-override-at, and the `t` of every
 * timeline entry, are seconds since the driver asked CNCjs to start the program
 * ('gcode:start'); entries before that have negative t.
 *
 * How it works (everything below is CNCjs's own API, see README.md):
 *  - writes a private config file (--config) holding a random `secret`, and
 *    starts `cncjs --host 127.0.0.1 --port <free port> --config <file>
 *    --controller Grbl` as a child process (HOME pointed at a temp dir);
 *  - signs an HS256 JWT {id:'',name:''} with that secret (what CNCjs's
 *    /api/signin hands out when no users are configured) and connects
 *    socket.io with ?token=<jwt>;
 *  - 'open' the port {controllerType:'Grbl', baudrate}, waits until CNCjs has
 *    parsed a status report and the answer to the `$$` it sends on init,
 *  - 'command' 'gcode:load' then 'gcode:start'; 'feedhold', 'cyclestart',
 *    'feedOverride' at the given times;
 *  - done when CNCjs's own end-of-program logic stops the workflow (all lines
 *    acknowledged and Grbl Idle for > 0.5 s).
 * Exit status: 0 completed, 1 Grbl/CNCjs reported an error or alarm, 2 bad
 * usage, 3 timeout, 4 CNCjs could not be started / connect / open the port.
 * The CNCjs server is killed on every exit path (and exits by itself if this
 * process dies: it watches its stdin pipe).
 */
'use strict';

const childProcess = require('child_process');
const crypto = require('crypto');
const fs = require('fs');
const http = require('http');
const net = require('net');
const os = require('os');
const path = require('path');

const EXIT_OK = 0;
const EXIT_JOB_ERROR = 1;
const EXIT_USAGE = 2;
const EXIT_TIMEOUT = 3;
const EXIT_SETUP = 4;

// ---------------------------------------------------------------- arguments

function usage(msg) {
  if (msg) {
    process.stderr.write(`cncjs_job: ${msg}\n`);
  }
  process.stderr.write(
    'usage: node cncjs_job.js --port /dev/pts/N --program FILE\n' +
    '         [--hold-at SECONDS --resume-at SECONDS] [--hold-command feedhold|pause]\n' +
    '         [--feed-override-at SECONDS:PERCENT]... [--timeout SECONDS]\n' +
    '         [--ready-timeout SECONDS] [--baudrate N] [--verbose] [--keep-tmp]\n');
  process.exit(EXIT_USAGE);
}

function parseArgs(argv) {
  const opts = {
    port: null,
    program: null,
    holdAt: null,
    resumeAt: null,
    holdCommand: 'feedhold',
    feedOverrides: [],
    timeout: 120,
    readyTimeout: 20,
    baudrate: 115200,
    verbose: false,
    keepTmp: false,
  };
  const num = (name, v) => {
    const n = Number(v);
    if (v === undefined || !Number.isFinite(n) || n < 0) {
      usage(`${name} needs a non-negative number, got ${JSON.stringify(v)}`);
    }
    return n;
  };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    const next = () => argv[++i];
    switch (a) {
      case '--port': opts.port = next(); break;
      case '--program': opts.program = next(); break;
      case '--hold-at': opts.holdAt = num(a, next()); break;
      case '--resume-at': opts.resumeAt = num(a, next()); break;
      case '--hold-command': opts.holdCommand = next(); break;
      case '--timeout': opts.timeout = num(a, next()); break;
      case '--ready-timeout': opts.readyTimeout = num(a, next()); break;
      case '--baudrate': opts.baudrate = num(a, next()); break;
      case '--verbose': opts.verbose = true; break;
      case '--keep-tmp': opts.keepTmp = true; break;
      case '--feed-override-at': {
        const v = next() || '';
        const m = v.match(/^([0-9.]+):([0-9]+)$/);
        if (!m) {
          usage(`--feed-override-at wants SECONDS:PERCENT, got ${JSON.stringify(v)}`);
        }
        const pct = Number(m[2]);
        if (pct < 10 || pct > 200) {
          usage(`--feed-override-at: Grbl's feed override is 10..200 %, got ${pct}`);
        }
        opts.feedOverrides.push({ at: num(a, m[1]), percent: pct });
        break;
      }
      case '-h':
      case '--help': usage(); break;
      default: usage(`unknown argument ${JSON.stringify(a)}`);
    }
  }
  if (!opts.port) usage('--port is required');
  if (!opts.program) usage('--program is required');
  if (!fs.existsSync(opts.program)) usage(`program file not found: ${opts.program}`);
  if (!['feedhold', 'pause'].includes(opts.holdCommand)) {
    usage('--hold-command is feedhold (CNCjs "feedhold"/"cyclestart": ! and ~) ' +
      'or pause (CNCjs "gcode:pause"/"gcode:resume": also stops streaming)');
  }
  if ((opts.holdAt === null) !== (opts.resumeAt === null)) {
    usage('--hold-at and --resume-at go together');
  }
  if (opts.holdAt !== null && opts.resumeAt <= opts.holdAt) {
    usage('--resume-at must be later than --hold-at');
  }
  return opts;
}

// ---------------------------------------------------------------- helpers

function findCncjs() {
  const pkgJson = require.resolve('cncjs/package.json', { paths: [__dirname] });
  const dir = path.dirname(pkgJson);
  return { dir, version: require(pkgJson).version, bin: path.join(dir, 'bin', 'cncjs') };
}

function freePort() {
  return new Promise((resolve, reject) => {
    const srv = net.createServer();
    srv.unref();
    srv.on('error', reject);
    srv.listen(0, '127.0.0.1', () => {
      const { port } = srv.address();
      srv.close(() => resolve(port));
    });
  });
}

function b64url(buf) {
  return Buffer.from(buf).toString('base64').replace(/=+$/, '').replace(/\+/g, '-').replace(/\//g, '_');
}

// HS256 JWT, the same thing jsonwebtoken.sign(payload, secret) produces.
function signToken(payload, secret) {
  const header = b64url(JSON.stringify({ alg: 'HS256', typ: 'JWT' }));
  const body = b64url(JSON.stringify({ ...payload, iat: Math.floor(Date.now() / 1000) }));
  const sig = b64url(crypto.createHmac('sha256', secret).update(`${header}.${body}`).digest());
  return `${header}.${body}.${sig}`;
}

function httpUp(port) {
  return new Promise((resolve) => {
    const req = http.get({ host: '127.0.0.1', port, path: '/', timeout: 1000 }, (res) => {
      res.resume();
      resolve(true);
    });
    req.on('timeout', () => { req.destroy(); resolve(false); });
    req.on('error', () => resolve(false));
  });
}

// CNCjs parses "Hold:0" into activeState 'Hold', subState 0, but also gives
// subState 0 (Number('')) to states without one: only Hold and Door have one.
function subStateOf(status) {
  const st = status.activeState;
  return (st === 'Hold' || st === 'Door') && Number.isFinite(status.subState) ? status.subState : null;
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

// Launcher run inside the child: exit when our stdin pipe closes (that is,
// when this driver dies, however it dies), then hand over to CNCjs's own bin.
const CHILD_LAUNCHER = `
process.stdin.on('end', () => process.exit(0));
process.stdin.on('error', () => process.exit(0));
process.stdin.resume();
const bin = process.argv[1];
process.argv = [process.argv[0], bin].concat(process.argv.slice(2));
require(bin);
`;

// ---------------------------------------------------------------- the job

class Job {
  constructor(opts) {
    this.opts = opts;
    this.cncjs = findCncjs();
    this.tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'cncjs-job-'));
    this.child = null;
    this.childExited = false;
    this.socket = null;
    this.finished = false;
    this.tStart = null; // ms epoch of gcode:start
    this.tLaunch = Date.now();
    this.timers = [];

    this.opened = false;
    this.status = null; // CNCjs's parsed status (controller:state .status)
    this.parserstate = null;
    this.settings = null;
    this.settingsLinesSeen = 0;
    this.settingsOkSeen = false;
    this.sender = null; // last sender:status with sent/received > 0
    this.senderLast = null;
    this.workflow = 'idle';
    this.sawRunning = false;
    this.requestedPause = false;

    this.errors = [];
    this.alarms = [];
    this.reads = [];
    this.writes = [];
    this.stateTimeline = [];
    this.workflowTimeline = [];
    this.actions = [];
    this.waiters = [];
    this.lastStateKey = null;
  }

  // Entries carry `t` = epoch ms while running; toRel() turns them into
  // seconds since gcode:start (negative before it) for the output.
  t() {
    return Date.now();
  }

  toRel(arr) {
    const ref = this.tStart === null ? this.tLaunch : this.tStart;
    return arr.map((e) => ({ ...e, t: Math.round(e.t - ref) / 1000 }));
  }

  log(msg) {
    if (this.opts.verbose) {
      process.stderr.write(`[cncjs_job ${((Date.now() - this.tLaunch) / 1000).toFixed(3)}] ${msg}\n`);
    }
  }

  // -------------------------------------------------- CNCjs server process
  async startServer() {
    const secret = crypto.randomBytes(24).toString('hex');
    this.secret = secret;
    const configFile = path.join(this.tmp, 'cncrc.json');
    fs.writeFileSync(configFile, JSON.stringify({ secret, allowRemoteAccess: false }, null, 2));
    this.serverLog = path.join(this.tmp, 'cncjs-server.log');

    for (let attempt = 1; attempt <= 3; attempt++) {
      const port = await freePort();
      const args = [
        '-e', CHILD_LAUNCHER, this.cncjs.bin,
        '--host', '127.0.0.1', '--port', String(port),
        '--config', configFile, '--controller', 'Grbl',
      ];
      if (this.opts.verbose) args.push('-vvv');
      this.childExited = false;
      const child = childProcess.spawn(process.execPath, args, {
        cwd: this.tmp,
        env: { ...process.env, HOME: this.tmp, NODE_ENV: 'production', FORCE_COLOR: '0' },
        stdio: ['pipe', 'pipe', 'pipe'],
      });
      this.child = child;
      // the server's output goes to its log file (and, with --verbose, to our stderr)
      for (const stream of [child.stdout, child.stderr]) {
        stream.on('data', (chunk) => {
          try { fs.appendFileSync(this.serverLog, chunk); } catch (e) { /* ignore */ }
          if (this.opts.verbose) process.stderr.write(String(chunk).replace(/^(?=.)/gm, '[cncjs-server] '));
        });
      }
      child.on('exit', (code, sig) => {
        this.childExited = true;
        this.log(`CNCjs server exited code=${code} signal=${sig}`);
        if (!this.finished && this.socket) {
          this.fail(EXIT_SETUP, `CNCjs server exited unexpectedly (code=${code}, signal=${sig}); see its log`);
        }
      });
      child.stdin.on('error', () => {});
      this.log(`started CNCjs ${this.cncjs.version} pid=${child.pid} on 127.0.0.1:${port}`);

      const deadline = Date.now() + 30000;
      while (Date.now() < deadline && !this.childExited) {
        if (await httpUp(port)) {
          this.httpPort = port;
          return;
        }
        await sleep(200);
      }
      await this.killServer();
      this.log(`CNCjs did not come up on port ${port} (attempt ${attempt})`);
    }
    throw Object.assign(new Error('could not start the CNCjs server (see its log)'), { exitCode: EXIT_SETUP });
  }

  killServer() {
    const child = this.child;
    if (!child || this.childExited) return Promise.resolve();
    return new Promise((resolve) => {
      const done = () => { clearTimeout(hard); resolve(); };
      child.once('exit', done);
      try { child.stdin.end(); } catch (e) { /* ignore */ }
      try { child.kill('SIGTERM'); } catch (e) { /* ignore */ }
      const hard = setTimeout(() => {
        try { child.kill('SIGKILL'); } catch (e) { /* ignore */ }
        setTimeout(resolve, 500);
      }, 3000);
    });
  }

  // -------------------------------------------------- socket.io
  connect() {
    const io = require(require.resolve('socket.io-client', { paths: [__dirname] }));
    const token = signToken({ id: '', name: '' }, this.secret);
    return new Promise((resolve, reject) => {
      const socket = io(`http://127.0.0.1:${this.httpPort}`, {
        query: `token=${token}`,
        transports: ['websocket'],
        reconnection: false,
        forceNew: true,
        timeout: 10000,
      });
      this.socket = socket;
      let settled = false;
      const settle = (err) => {
        if (settled) return;
        settled = true;
        if (err) reject(Object.assign(new Error(err), { exitCode: EXIT_SETUP }));
        else resolve();
      };
      socket.on('connect_error', (e) => settle(`socket.io connect error: ${e && e.message ? e.message : e}`));
      socket.on('connect_timeout', () => settle('socket.io connect timeout'));
      socket.on('error', (e) => settle(`socket.io error (authentication?): ${JSON.stringify(e)}`));
      socket.on('disconnect', (reason) => {
        this.log(`socket disconnected: ${reason}`);
        if (!this.finished) this.fail(EXIT_SETUP, `CNCjs socket disconnected: ${reason}`);
      });
      socket.on('startup', (data) => {
        this.log(`startup ${JSON.stringify(data)}`);
        settle(null);
      });
      this.installHandlers(socket);
    });
  }

  installHandlers(socket) {
    socket.on('serialport:open', (o) => {
      this.log(`serialport:open ${JSON.stringify(o)}`);
      this.opened = true;
      this.wake();
    });
    socket.on('serialport:close', (o) => {
      this.log(`serialport:close ${JSON.stringify(o)}`);
      if (!this.finished && this.opened) {
        this.fail(EXIT_SETUP, `CNCjs reports the serial port closed: ${JSON.stringify(o)}`);
      }
    });
    socket.on('serialport:error', (o) => {
      // the Error object does not survive socket.io; its text is in the server log
      setTimeout(() => {
        const why = this.serverLogErrors().pop() || JSON.stringify(o);
        this.fail(EXIT_SETUP, `CNCjs could not open ${this.opts.port}: ${why}`);
      }, 300);
    });
    socket.on('serialport:read', (line) => this.onRead(String(line)));
    socket.on('serialport:write', (data, ctx) => {
      const src = ctx && ctx.source ? ctx.source : '';
      this.writes.push({ t: this.t(), data: String(data), source: src });
    });
    socket.on('controller:settings', (type, settings) => {
      this.settings = settings;
      this.wake();
    });
    socket.on('controller:state', (type, state) => {
      this.status = (state && state.status) || null;
      this.parserstate = (state && state.parserstate) || null;
      if (this.status && this.status.activeState) {
        const st = this.status.activeState;
        const sub = subStateOf(this.status);
        const key = `${st}:${sub === null ? '' : sub}`;
        if (key !== this.lastStateKey) {
          this.lastStateKey = key;
          const e = { t: this.t(), state: st };
          if (sub !== null) e.substate = sub;
          this.stateTimeline.push(e);
          this.log(`state ${st}${sub === null ? '' : `:${sub}`}`);
        }
      }
      this.wake();
    });
    socket.on('sender:status', (s) => {
      this.senderLast = s;
      if (s && (s.sent > 0 || s.received > 0)) this.sender = s;
      this.wake();
    });
    socket.on('workflow:state', (ws) => {
      this.workflow = ws;
      this.workflowTimeline.push({ t: this.t(), state: ws });
      this.log(`workflow ${ws}`);
      if (ws === 'running') {
        this.sawRunning = true;
        this.requestedPause = false;
      }
      this.wake();
    });
  }

  onRead(line) {
    this.reads.push({ t: this.t(), line });
    if (/^error:/i.test(line)) {
      this.errors.push({ t: this.t(), line });
    } else if (/^ALARM:/i.test(line)) {
      this.alarms.push({ t: this.t(), line });
    } else if (/^\$\d+=/.test(line)) {
      this.settingsLinesSeen++;
    } else if (line === 'ok' && this.settingsLinesSeen > 0) {
      this.settingsOkSeen = true;
    }
    this.wake();
  }

  // wait until cond() holds (re-checked on every event and every 100 ms)
  waitFor(cond, ms, what) {
    return new Promise((resolve, reject) => {
      const w = { cond, resolve, reject };
      const check = () => {
        if (this.finished) return;
        let ok;
        try {
          ok = cond();
        } catch (e) {
          clearInterval(w.iv);
          clearTimeout(w.to);
          this.waiters = this.waiters.filter((x) => x !== w);
          reject(e);
          return;
        }
        if (ok) {
          clearInterval(w.iv);
          clearTimeout(w.to);
          this.waiters = this.waiters.filter((x) => x !== w);
          resolve();
        }
      };
      w.check = check;
      w.iv = setInterval(check, 100);
      w.to = setTimeout(() => {
        clearInterval(w.iv);
        this.waiters = this.waiters.filter((x) => x !== w);
        reject(Object.assign(new Error(`timed out waiting for ${what}`), { exitCode: EXIT_TIMEOUT }));
      }, ms);
      this.waiters.push(w);
      check();
    });
  }

  wake() {
    for (const w of this.waiters.slice()) w.check();
  }

  emitCommand(cmd, ...args) {
    this.actions.push({ t: this.t(), command: cmd, args });
    this.log(`command ${cmd} ${JSON.stringify(args).slice(0, 200)}`);
    this.socket.emit('command', this.opts.port, cmd, ...args);
  }

  openPort() {
    return new Promise((resolve, reject) => {
      this.socket.emit('open', this.opts.port, {
        controllerType: 'Grbl',
        baudrate: this.opts.baudrate,
        rtscts: false,
      }, (err) => {
        if (err) {
          // the Error object does not survive socket.io; its text is in the server log
          setTimeout(() => {
            const m = this.serverLogErrors().pop() || (err && err.message) || JSON.stringify(err);
            reject(Object.assign(new Error(`CNCjs could not open ${this.opts.port}: ${m}`), { exitCode: EXIT_SETUP }));
          }, 300);
        } else {
          resolve();
        }
      });
    });
  }

  loadProgram(name, gcode) {
    return new Promise((resolve, reject) => {
      this.emitCommand('gcode:load', name, gcode, {}, (err, data) => {
        if (err) reject(Object.assign(new Error(`gcode:load failed: ${JSON.stringify(err)}`), { exitCode: EXIT_SETUP }));
        else resolve(data);
      });
      // keep the callback out of the recorded action
      this.actions[this.actions.length - 1].args = [name, `<${gcode.length} bytes>`];
    });
  }

  feedOverrideTo(percent) {
    // CNCjs's 'feedOverride' takes a step: 0 (=100 %, 0x90), 10 (0x91), -10 (0x92), 1 (0x93), -1 (0x94)
    this.emitCommand('feedOverride', 0);
    const diff = percent - 100;
    const tens = Math.trunc(diff / 10);
    const ones = diff - tens * 10;
    for (let i = 0; i < Math.abs(tens); i++) this.emitCommand('feedOverride', tens > 0 ? 10 : -10);
    for (let i = 0; i < Math.abs(ones); i++) this.emitCommand('feedOverride', ones > 0 ? 1 : -1);
  }

  schedule(atSeconds, fn) {
    const delay = Math.max(0, this.tStart + atSeconds * 1000 - Date.now());
    this.timers.push(setTimeout(() => { if (!this.finished) fn(); }, delay));
  }

  async run() {
    const o = this.opts;
    const deadline = this.tLaunch + o.timeout * 1000;
    const left = () => Math.max(1, deadline - Date.now());
    this.globalTimer = setTimeout(() => this.fail(EXIT_TIMEOUT, `timeout after ${o.timeout} s ` +
      `(phase: ${this.phase}; workflow=${this.workflow}, state=${this.status && this.status.activeState}, ` +
      `sender=${this.sender ? `${this.sender.received}/${this.sender.sent}/${this.sender.total}` : '-'})`), left());

    this.phase = 'starting CNCjs';
    await this.startServer();
    this.phase = 'connecting socket.io';
    await this.connect();
    this.phase = 'opening the port';
    await this.openPort();
    this.log('port opened');

    // Ready: CNCjs has parsed a status report (it sets its `ready` flag on the
    // startup banner or on the first status report) and the `$$` it sends on
    // init was answered (settings lines then `ok`). Only then is the `ok` of
    // `$$` safely out of the way of the program's acknowledgements.
    this.phase = 'waiting for CNCjs to see Grbl (banner or status report)';
    await this.waitFor(() => this.status && this.status.activeState, Math.min(left(), o.readyTimeout * 1000),
      'a status report parsed by CNCjs (does the device answer `?` with <...|MPos:...>?)');
    this.phase = 'waiting for the answer to $$';
    await this.waitFor(() => this.settingsOkSeen, Math.min(left(), o.readyTimeout * 1000),
      'the answer to CNCjs\'s `$$` ($N=V lines, then ok)');
    this.phase = 'waiting for Grbl to be Idle';
    await this.waitFor(() => {
      if (this.status.activeState === 'Alarm') {
        throw Object.assign(new Error('Grbl is in Alarm state; CNCjs will not stream'), { exitCode: EXIT_JOB_ERROR });
      }
      return this.status.activeState === 'Idle';
    }, Math.min(left(), o.readyTimeout * 1000), 'Grbl to report Idle before the job');
    await sleep(300); // let the init $G round trip settle, as a user would

    this.phase = 'loading the program';
    const gcode = fs.readFileSync(o.program, 'utf8');
    this.programLines = gcode.split('\n').filter((l) => l.trim().length > 0).length;
    const loaded = await this.loadProgram(path.basename(o.program), gcode);
    this.log(`loaded: total=${loaded && loaded.total}`);

    this.phase = 'running the program';
    this.tStart = Date.now();
    this.emitCommand('gcode:start');
    if (o.holdAt !== null) {
      const pause = o.holdCommand === 'pause';
      this.schedule(o.holdAt, () => {
        if (pause) this.requestedPause = true;
        this.emitCommand(pause ? 'gcode:pause' : 'feedhold');
      });
      // requestedPause is cleared when CNCjs reports the workflow running again
      this.schedule(o.resumeAt, () => this.emitCommand(pause ? 'gcode:resume' : 'cyclestart'));
    }
    for (const f of o.feedOverrides) this.schedule(f.at, () => this.feedOverrideTo(f.percent));

    let trouble = null;
    await this.waitFor(() => {
      if (this.alarms.length > 0 || (this.workflow === 'paused' && !this.requestedPause)) {
        trouble = true;
        return true;
      }
      return this.sawRunning && this.workflow === 'idle' && this.sender &&
        this.sender.total > 0 && this.sender.received >= this.sender.total &&
        this.status && this.status.activeState === 'Idle';
    }, left(), 'the end of the program');
    if (trouble) {
      // CNCjs emits sender:status on a 250 ms tick: give it time to report
      // the counts and the hold reason before we stop.
      await sleep(700);
      if (this.alarms.length > 0) {
        throw Object.assign(new Error(`Grbl raised an alarm: ${this.alarms[0].line}`), { exitCode: EXIT_JOB_ERROR });
      }
      const reason = this.senderLast && this.senderLast.holdReason;
      let why = reason ? (reason.msg || reason.data || JSON.stringify(reason)) : null;
      if (!why && this.errors.length > 0) why = this.errors[0].line;
      throw Object.assign(new Error(`CNCjs paused the program: ${why || 'unknown reason'}` +
        (reason && !reason.err ? ' (M0/M1/M6 in the program wait for a user to resume)' : '')),
      { exitCode: EXIT_JOB_ERROR });
    }
    if (this.errors.length > 0) {
      throw Object.assign(new Error(`Grbl answered with ${this.errors.length} error(s), first: ${this.errors[0].line}`),
        { exitCode: EXIT_JOB_ERROR });
    }
    this.phase = 'done';
  }

  result(code, message) {
    const s = this.status || {};
    const snd = this.sender || this.senderLast || {};
    const r = {
      sender: 'cncjs',
      sender_version: this.cncjs.version,
      ok: code === EXIT_OK,
      result: code === EXIT_OK ? 'completed' : (code === EXIT_TIMEOUT ? 'timeout' : 'error'),
      message: message || null,
      port: this.opts.port,
      program: this.opts.program,
      program_lines: this.programLines === undefined ? null : this.programLines,
      lines_total: snd.total === undefined ? null : snd.total,
      lines_sent: snd.sent === undefined ? null : snd.sent,
      lines_received: snd.received === undefined ? null : snd.received,
      errors: this.toRel(this.errors),
      alarms: this.toRel(this.alarms),
      last_status: this.status ? {
        state: s.activeState,
        substate: subStateOf(s),
        mpos: s.mpos || null,
        wpos: s.wpos || null,
        wco: s.wco || null,
        ov: s.ov || null,
        buf: s.buf || null,
        feedrate: s.feedrate === undefined ? null : s.feedrate,
        spindle: s.spindle === undefined ? null : s.spindle,
      } : null,
      parserstate: this.parserstate,
      firmware_version: this.settings ? this.settings.version || null : null,
      settings_received: this.settings && this.settings.settings ? Object.keys(this.settings.settings).length : 0,
      state_timeline: this.toRel(this.stateTimeline),
      workflow_timeline: this.toRel(this.workflowTimeline),
      actions: this.toRel(this.actions),
      client_writes: this.toRel(this.writes),
      serial_read_tail: this.toRel(this.reads.slice(-60)),
      elapsed_s: this.tStart === null ? null : Math.round(Date.now() - this.tStart) / 1000,
    };
    if (code !== EXIT_OK || this.opts.verbose) {
      r.server_log_tail = this.serverLogTail();
    }
    return r;
  }

  serverLogErrors() {
    const tail = this.serverLogTail() || '';
    return tail.split('\n')
      .map((l) => l.replace(/\x1b\[[0-9;]*m/g, '')) // eslint-disable-line no-control-regex
      .filter((l) => / error /.test(l))
      .map((l) => l.replace(/^\S+ - error /, ''));
  }

  serverLogTail() {
    try {
      const txt = fs.readFileSync(this.serverLog, 'utf8');
      return txt.split('\n').slice(-40).join('\n');
    } catch (e) {
      return null;
    }
  }

  fail(code, message) {
    return this.finish(code, message);
  }

  async finish(code, message) {
    if (this.finished) return;
    this.finished = true;
    clearTimeout(this.globalTimer);
    this.timers.forEach(clearTimeout);
    for (const w of this.waiters) { clearInterval(w.iv); clearTimeout(w.to); }
    const out = this.result(code, message);
    if (code !== EXIT_OK) {
      process.stderr.write(`cncjs_job: ${message}\n`);
    }
    if (this.socket) {
      try {
        if (this.opened) this.socket.emit('close', this.opts.port);
        await sleep(200);
        this.socket.close();
      } catch (e) { /* ignore */ }
    }
    await this.killServer();
    if (this.opts.keepTmp) {
      process.stderr.write(`cncjs_job: temp dir kept (config, CNCjs server log): ${this.tmp}\n`);
    } else {
      fs.rmSync(this.tmp, { recursive: true, force: true });
    }
    process.stdout.write(`${JSON.stringify(out)}\n`, () => process.exit(code));
  }
}

// ---------------------------------------------------------------- main

function main() {
  const opts = parseArgs(process.argv.slice(2));
  let job;
  try {
    job = new Job(opts);
  } catch (e) {
    process.stderr.write(`cncjs_job: cannot find CNCjs (run \`npm ci\` in ${__dirname}): ${e.message}\n`);
    process.exit(EXIT_SETUP);
  }
  const onSignal = (sig) => job.fail(EXIT_SETUP, `interrupted by ${sig}`);
  process.on('SIGINT', onSignal);
  process.on('SIGTERM', onSignal);
  process.on('SIGHUP', onSignal);
  process.on('exit', () => {
    // last resort: never leave the server behind
    if (job.child && !job.childExited) {
      try { job.child.kill('SIGKILL'); } catch (e) { /* ignore */ }
    }
  });
  process.on('uncaughtException', (e) => job.fail(EXIT_SETUP, `internal error: ${e && e.stack ? e.stack : e}`));
  job.run().then(
    () => job.finish(EXIT_OK, null),
    (e) => job.fail(e.exitCode || EXIT_SETUP, e.message),
  );
}

main();
