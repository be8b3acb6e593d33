// The operator's page: the service's API (docs/api.md) from a logged-in
// browser. Every call that changes state carries the page's CSRF token.
'use strict';

const csrf = document.querySelector('meta[name="csrf-token"]').content;
const $ = (id) => document.getElementById(id);
let jobs = [];
let status = null;
let chosen = null;      // the job whose picture is shown
let mapping = null;     // the picture's mm → viewBox mapping

const STATE_WORDS = {
  Idle: 'ready',
  Run: 'moving: a job or a move runs',
  'Hold:0': 'held: standing still, laser off; Resume goes on',
  'Hold:1': 'stopping: braking to a hold, laser off',
  Jog: 'jogging',
  Home: 'homing',
  Alarm: 'alarm: motion is locked (a limit, a lost position, or a reset while moving); Unlock or Home',
  Check: 'check mode: G-code is parsed, nothing moves',
  Sleep: 'asleep',
  Disconnected: 'no controller link',
};

function words(state) {
  if (STATE_WORDS[state]) return STATE_WORDS[state];
  if (state && state.startsWith('Door')) return 'the safety door is open: the laser stays off until it is closed and the job resumed';
  return '';
}

/** A duration as people read it: 1 h 19 min 29 s, 4 min 3 s, 29.4 s. */
function duration(s) {
  if (s === null || s === undefined || !isFinite(s)) return '–';
  if (s < 60) return `${s.toFixed(1)} s`;
  const total = Math.round(s);
  const h = Math.floor(total / 3600), m = Math.floor((total % 3600) / 60), sec = total % 60;
  return h > 0 ? `${h} h ${m} min ${sec} s` : `${m} min ${sec} s`;
}

function mm(v) { return Number(v).toFixed(2); }

function showError(text) {
  const e = $('error');
  e.textContent = text || '';
  e.hidden = !text;
}

async function api(method, path, body, raw) {
  const headers = { 'X-CSRF-Token': csrf };
  let payload;
  if (raw !== undefined) { payload = raw; }
  else if (body !== undefined) { headers['Content-Type'] = 'application/json'; payload = JSON.stringify(body); }
  const response = await fetch(path, { method, headers, body: payload, credentials: 'same-origin' });
  if (response.status === 401) { window.location.reload(); throw new Error('logged out'); }
  const type = response.headers.get('Content-Type') || '';
  const answer = type.startsWith('application/json') ? await response.json() : await response.text();
  if (!response.ok) throw new Error(answer && answer.error ? answer.error : `${response.status}`);
  return answer;
}

async function act(method, path, body) {
  try {
    const answer = await api(method, path, body);
    showError('');
    return answer;
  } catch (e) {
    showError(`${method} ${path}: ${e.message}`);
    return null;
  }
}

function button(text, id, onclick, cls) {
  const b = document.createElement('button');
  b.textContent = text;
  b.id = id;
  if (cls) b.className = cls;
  b.addEventListener('click', (e) => { e.stopPropagation(); onclick(); });
  return b;
}

function cell(row, text) {
  const td = row.insertCell();
  td.textContent = text;
  return td;
}

// ---- status ----

function showStatus(s) {
  status = s;
  const m = s.machine;
  const badge = $('state');
  badge.textContent = m.state;
  badge.className = 'badge ' + m.state.split(':')[0];
  $('state-words').textContent = words(m.state);
  const alarm = $('machine-alarm');
  alarm.hidden = !m.alarm;
  alarm.textContent = m.alarm ? `${m.alarm}. Unlock clears it; Home finds the machine's position again.` : '';
  $('origin').textContent = s.origin ? `X ${mm(s.origin[0])}  Y ${mm(s.origin[1])}` : 'as the config places them';
  const msg = $('machine-message');
  msg.hidden = !m.message;
  msg.textContent = m.message || '';
  const p = m.position || [];
  $('pos-stage').textContent = p.length >= 2 ? `X ${mm(p[0])}  Y ${mm(p[1])}` : '–';
  $('row-scanner').hidden = p.length < 4;
  if (p.length >= 4) $('pos-scanner').textContent = `U ${mm(p[2])}  V ${mm(p[3])}`;
  $('controller').textContent = m.connected ? `firmware ${m.controller || 'unknown'}; ${m.message ? 'settings: see above' : 'settings agree with the config'}` : '–';
  $('pos-tcp').textContent = m.tcp ? `X ${mm(m.tcp[0])}  Y ${mm(m.tcp[1])}` : '–';
  $('laser').textContent = m.connected ? `${m.laser}` : '–';
  $('feed').textContent = m.connected ? `${Math.round(m.feed)} mm/min` : '–';
  $('overrides').textContent = m.overrides ? m.overrides.map((v) => `${v} %`).join(', ') : '–';
  $('storage').textContent = s.storage || 'ok';
  showProgress(s.job);
  moveTool(m.tcp);
  enableButtons();
}

let lastRun = null;  // the last job seen running: shown as it ended

function showProgress(job) {
  if (!job && lastRun) job = ended(lastRun);
  $('running-none').hidden = !!job;
  $('running-job').hidden = !job;
  if (!job) return;
  if (job.state === 'running' || job.state === 'paused') lastRun = job;
  const record = jobs.find((j) => j.id === job.id);
  $('running-name').textContent = `${record ? record.name : job.id} (${job.id}), ${job.state}`;
  const byTime = job.time_percent !== null && job.time_percent !== undefined ? job.time_percent : job.percent;
  $('progress-time').value = byTime;
  $('percent-time').textContent = `${byTime.toFixed(1)} %`;
  $('progress-line').value = job.percent;
  $('percent-line').textContent = `${job.percent.toFixed(1)} % (line ${job.executed_line ?? '?'} of ${job.lines_total})`;
  $('elapsed').textContent = duration(job.elapsed_s);
  $('eta').textContent = duration(job.eta_s);
  $('ends-at').textContent = job.eta_s !== null && job.eta_s !== undefined ? new Date(Date.now() + job.eta_s * 1000).toLocaleTimeString() : '–';
  $('executed-line').textContent = job.executed_line ?? 'unknown';
}

/** A job's progress as it ended, from its record. */
function ended(last) {
  const j = jobs.find((x) => x.id === last.id);
  if (!j || !['completed', 'aborted', 'failed', 'interrupted'].includes(j.state)) return last;
  const lines = j.last_executed_line ?? last.executed_line ?? 0;
  return {
    id: j.id, state: j.state, line: j.last_acked_line, lines_total: j.lines_total, executed_line: lines,
    percent: j.lines_total ? (100 * lines) / j.lines_total : 0,
    time_percent: j.state === 'completed' ? 100 : last.time_percent,
    elapsed_s: j.executed_time_s, eta_s: j.state === 'completed' ? 0 : null,
  };
}

function enableButtons() {
  const m = status ? status.machine : { state: 'Disconnected', connected: false };
  const running = !!(status && status.job);
  const idle = m.connected && m.state === 'Idle';
  for (const b of document.querySelectorAll('[data-jog]')) b.disabled = !idle && m.state !== 'Jog';
  $('home').disabled = !m.connected || running;
  $('unlock').disabled = !m.connected || running;
  $('set-origin').disabled = !m.tcp || running;
  $('clear-origin').disabled = !(status && status.origin);
  $('pause').disabled = !running || status.job.state !== 'running';
  $('resume').disabled = !running || status.job.state !== 'paused';
  $('abort').disabled = !running;
  for (const b of document.querySelectorAll('[data-start], [data-frame]')) b.disabled = !idle || running;
}

// ---- jobs ----

function isHistory(j) { return ['completed', 'aborted', 'failed', 'interrupted'].includes(j.state); }

async function loadJobs() {
  try {
    jobs = await api('GET', '/jobs');
  } catch (e) { showError(`the job list: ${e.message}`); return; }
  showQueue();
  showHistory();
  if (chosen && !jobs.find((j) => j.id === chosen)) { chosen = null; $('selected').hidden = true; }
  if (status) showProgress(status.job);
}

function showQueue() {
  const body = $('queue-table').tBodies[0];
  body.replaceChildren();
  const waiting = jobs.filter((j) => !isHistory(j) || j.state === 'interrupted');
  const queued = waiting.filter((j) => j.state === 'queued');
  for (const j of waiting) {
    const row = body.insertRow();
    row.id = `job-${j.id}`;
    if (j.id === chosen) row.className = 'chosen';
    row.addEventListener('click', () => choose(j.id));
    cell(row, `${j.name} (${j.id})`);
    cell(row, j.state + (j.message ? `: ${j.message}` : ''));
    cell(row, duration(j.planned_time_s));
    cell(row, j.lines_total ? `${j.lines_total}` : '–');
    const actions = row.insertCell();
    actions.className = 'actions';
    if (j.state === 'queued') {
      const at = queued.indexOf(j);
      const up = button('↑', `up-${j.id}`, () => act('POST', `/jobs/${j.id}/move`, { position: Math.max(0, at - 1) }).then(loadJobs));
      up.disabled = at === 0;
      actions.append(up);
      actions.append(button('↓', `down-${j.id}`, () => act('POST', `/jobs/${j.id}/move`, { position: at + 1 }).then(loadJobs)));
      const frame = button('Frame', `frame-${j.id}`, () => act('POST', '/frame', { id: j.id }));
      frame.dataset.frame = j.id;
      actions.append(frame);
      const start = button('Start', `start-${j.id}`, () => act('POST', '/start', { id: j.id }));
      start.dataset.start = j.id;
      actions.append(start);
    }
    if (j.state !== 'running' && j.state !== 'paused') {
      actions.append(button('Remove', `remove-${j.id}`, () => act('DELETE', `/jobs/${j.id}`).then(loadJobs), 'danger'));
    }
  }
  enableButtons();
}

function showHistory() {
  const body = $('history-table').tBodies[0];
  body.replaceChildren();
  for (const j of jobs.filter(isHistory)) {
    const row = body.insertRow();
    row.id = `history-${j.id}`;
    row.addEventListener('click', () => choose(j.id));
    cell(row, `${j.name} (${j.id})`);
    cell(row, j.state);
    cell(row, j.started_at ? new Date(j.started_at * 1000).toLocaleString() : '–');
    cell(row, duration(j.planned_time_s));
    cell(row, duration(j.executed_time_s));
    cell(row, `${j.last_executed_line ?? '?'} of ${j.lines_total}`);
    const files = row.insertCell();
    for (const [what, label] of [['program', 'program'], ['recording', 'recording (MCAP)']]) {
      const a = document.createElement('a');
      a.href = `/jobs/${j.id}/${what}`;
      a.textContent = label;
      a.download = '';
      files.append(a, ' ');
    }
    cell(row, j.message || (j.warnings || []).join('; '));
  }
}

async function choose(id) {
  chosen = id;
  const j = jobs.find((x) => x.id === id);
  if (!j) return;
  for (const row of $('queue-table').tBodies[0].rows) row.className = row.id === `job-${id}` ? 'chosen' : '';
  $('selected').hidden = false;
  $('selected-name').textContent = `${j.name} (${j.id})`;
  const figures = $('selected-figures');
  figures.replaceChildren();
  const f = j.figures || {};
  const rows = [
    ['State', j.state],
    ['Planned machine time', duration(j.planned_time_s)],
    ['Geometries', f.geometries ?? '–'],
    ['Scan fields', f.scan_fields ?? 'none (stage only)'],
    ['Marked length', f.mark_length_mm !== undefined ? `${(f.mark_length_mm / 1000).toFixed(3)} m` : '–'],
    ['Pierces', f.pierces ?? '–'],
    ['Size', j.bounds ? `${mm(j.bounds[2] - j.bounds[0])} × ${mm(j.bounds[3] - j.bounds[1])} mm at (${mm(j.bounds[0])}, ${mm(j.bounds[1])})` : '–'],
    ['Precedence violations', j.precedence_violations ?? '–'],
    ['Program lines', j.lines_total || '–'],
  ];
  for (const [k, v] of rows) {
    const row = figures.insertRow();
    const th = document.createElement('th');
    th.textContent = k;
    row.append(th);
    cell(row, `${v}`);
  }
  mapping = null;
  $('plot').removeAttribute('src');
  if (j.state === 'planning' || (j.state === 'failed' && !j.lines_total)) return;
  try {
    const svg = await api('GET', `/jobs/${id}/plot`);
    const box = /viewBox="([^"]+)"/.exec(svg);
    const map = /data-mm-to-px="([^"]+)"/.exec(svg);
    if (box) $('overlay').setAttribute('viewBox', box[1]);
    mapping = map ? map[1].split(/\s+/).map(Number) : null;
    $('plot').src = `/jobs/${id}/plot`;
  } catch (e) {
    $('plot').alt = `no picture: ${e.message}`;
  }
  moveTool(status && status.machine.tcp);
}

function moveTool(tcp) {
  const tool = $('tool');
  if (!mapping || !tcp) { tool.setAttribute('r', '0'); return; }
  const [ox, oy, s] = mapping;
  const box = ($('overlay').getAttribute('viewBox') || '0 0 100 100').split(/\s+/).map(Number);
  tool.setAttribute('cx', ox + s * tcp[0]);
  tool.setAttribute('cy', oy - s * tcp[1]);
  tool.setAttribute('r', Math.max(box[2], box[3]) / 90);
}

// ---- uploads ----

async function upload(files) {
  for (const file of files) {
    try {
      const job = await api('POST', `/jobs?name=${encodeURIComponent(file.name)}`, undefined, file);
      chosen = job.id;
      showError('');
    } catch (e) {
      showError(`${file.name}: ${e.message}`);
    }
  }
  await loadJobs();
}

// ---- controls ----

function jogBlock(axis, sign) {
  const step = $('jog-step').value;
  const feed = Number($('jog-feed').value) || 1000;
  // Hold to move: a long move, cancelled on release.
  const distance = step === 'cont' ? 10000 : Number(step);
  return `G91 G21 ${axis}${(sign * distance).toFixed(3)} F${feed}`;
}

function wire() {
  $('logout').addEventListener('click', async () => { await fetch('/logout', { method: 'POST', headers: { 'X-CSRF-Token': csrf } }); window.location.reload(); });
  for (const b of document.querySelectorAll('[data-jog]')) {
    const axis = b.dataset.jog[0], sign = b.dataset.jog.includes('-') ? -1 : 1;
    b.addEventListener('pointerdown', () => act('POST', '/jog', { block: jogBlock(axis, sign) }));
    const release = () => { if ($('jog-step').value === 'cont' && status && status.machine.state === 'Jog') act('POST', '/abort'); };
    b.addEventListener('pointerup', release);
    b.addEventListener('pointerleave', release);
  }
  $('jog-stop').addEventListener('click', () => act('POST', '/abort'));
  $('home').addEventListener('click', () => act('POST', '/home'));
  $('unlock').addEventListener('click', () => act('POST', '/unlock'));
  $('set-origin').addEventListener('click', () => act('POST', '/origin'));
  $('clear-origin').addEventListener('click', () => act('DELETE', '/origin'));
  $('pause').addEventListener('click', () => act('POST', '/pause'));
  $('resume').addEventListener('click', () => act('POST', '/resume'));
  $('abort').addEventListener('click', () => act('POST', '/abort'));
  for (const b of document.querySelectorAll('[data-override]')) {
    const [, what, change] = /^(feed|power)(.*)$/.exec(b.dataset.override);
    b.addEventListener('click', () => act('POST', '/override', { [what]: change }));
  }
  const drop = $('drop');
  drop.addEventListener('dragover', (e) => { e.preventDefault(); drop.classList.add('over'); });
  drop.addEventListener('dragleave', () => drop.classList.remove('over'));
  drop.addEventListener('drop', (e) => { e.preventDefault(); drop.classList.remove('over'); upload(e.dataTransfer.files); });
  $('upload').addEventListener('change', (e) => { upload(e.target.files); e.target.value = ''; });
}

function listen() {
  const events = new EventSource('/events');
  events.addEventListener('status', (e) => showStatus(JSON.parse(e.data)));
  events.addEventListener('job', (e) => {
    const j = JSON.parse(e.data);
    const at = jobs.findIndex((x) => x.id === j.id);
    if (at >= 0) jobs[at] = j;
    // A new job, or one that changed state: the lists again, in the service's order.
    loadJobs().then(() => { if (j.id === chosen) choose(j.id); });
  });
  events.onerror = () => showError('the live link to the service is lost; retrying…');
  events.onopen = () => showError('');
}

wire();
loadJobs();
listen();
