// The page only sends keys and shows what the server's env draws: the dynamics live in the package, not here.
"use strict";
const GRID_KEYS = { ArrowUp: "up", ArrowDown: "down", ArrowLeft: "left", ArrowRight: "right" };
// An episode waits for the person's first key (or Start): the world does not step before they are there.
const game = { info: null, held: new Set(), moves: [], started: false, paused: false, done: false, outcome: "",
               busy: false };
const $ = (id) => document.getElementById(id);

async function api(path, body) {
  const options = body === undefined ? {} : {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) };
  const response = await fetch(path, options);
  const data = await response.json();
  if (!response.ok) throw new Error(data.error || response.statusText);
  return data;
}

function show(state) {
  $("frame").src = state.frame;
  $("outcome").textContent = state.outcome;
  $("step").textContent = state.step;
  $("return").textContent = state.return.toFixed(2);
  $("episode").textContent = state.episode;
  game.done = state.done;
  game.outcome = state.outcome;
  showStatus();
}

// The status line and the Start/Pause/Resume button say what the person's next key does.
function showStatus() {
  const status = $("status");
  Object.assign(status.dataset, { started: game.started, paused: game.paused, done: game.done });
  status.textContent = game.done ? `episode over: ${game.outcome}; R restarts`
    : !game.started ? "press an arrow key or space, or click Start, to begin"
    : game.paused ? "paused: space resumes" : "playing";
  $("pause").textContent = game.done ? "Pause (space)" : !game.started ? "Start"
    : game.paused ? "Resume (space)" : "Pause (space)";
  $("pause").disabled = game.done;
}

async function send(path, body) {
  game.busy = true;
  try {
    show(await api(path, body));
    $("error").textContent = "";
  } catch (error) {
    $("error").textContent = error.message;
  } finally {
    game.busy = false;
  }
}

function keysHeld() {
  const axis = (plus, minus) => (game.held.has(plus) ? 1 : 0) - (game.held.has(minus) ? 1 : 0);
  return { accelerate: axis("ArrowUp", "ArrowDown"), turn: axis("ArrowLeft", "ArrowRight") };
}

// The grid's move this step: a tap not yet played, else the arrow held last (none held: the grid has no "stay").
function gridMove() {
  const held = [...game.held].filter((key) => key in GRID_KEYS);
  return game.moves.shift() || (held.length ? GRID_KEYS[held[held.length - 1]] : undefined);
}

function tick() {
  if (!game.started || game.paused || game.done || game.busy || !game.info) return;
  if (game.info.domain === "discrete") {
    const move = gridMove();
    if (move) send("/api/step", { move });
  } else {
    send("/api/step", keysHeld());
  }
}

// Space starts, pauses and resumes; once the episode is over, the outcome stays on show until R.
function startOrPause() {
  if (game.done) return;
  if (game.started) game.paused = !game.paused;
  else game.started = true;
  showStatus();
}

function restart() {
  Object.assign(game, { moves: [], started: false, paused: false });
  send("/api/reset", {});
}

document.addEventListener("keydown", (event) => {
  if (event.key in GRID_KEYS) {
    event.preventDefault();
    if (event.repeat) return;
    game.held.delete(event.key);  // re-added last: the arrow pressed last leads
    game.held.add(event.key);
    if (game.moves.length < 8) game.moves.push(GRID_KEYS[event.key]);
    if (!game.started) startOrPause();  // the first arrow starts the episode, and is its first move
  } else if (event.key === " ") {
    event.preventDefault();
    startOrPause();
  } else if (event.key === "r" || event.key === "R") {
    restart();
  }
});
document.addEventListener("keyup", (event) => game.held.delete(event.key));
$("pause").addEventListener("click", startOrPause);
$("restart").addEventListener("click", restart);

(async () => {
  try {
    game.info = await api("/api/game");
  } catch (error) {
    $("error").textContent = error.message;
    return;
  }
  const settings = Object.entries(game.info.partner_settings).map(([k, v]) => `${k}=${v}`).join(", ");
  $("about").textContent = `${game.info.domain} sidewalk: you are the red agent (agent 0), walking to the red ` +
    `star, against ${game.info.partner}, ${game.info.steps_per_s} steps a second.`;
  $("settings").textContent = settings ? `Partner settings: ${settings}.` : "";
  $("keys").textContent = `Keys: ${game.info.keys}; space starts and pauses, R restarts.`;
  $("recording").textContent = game.info.recording ? `Episodes are saved to the dataset ${game.info.recording}.` : "Episodes are not saved.";
  show(await api("/api/state"));
  setInterval(tick, 1000 / game.info.steps_per_s);
})();
