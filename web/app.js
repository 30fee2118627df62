// The try-on page: loads the WebAssembly runtime (pkg/, made by wasm-bindgen), the shipped
// model with the fewest triangles (f16 on the wire; the others when chosen) and the body, then
// plays a motion on the body chosen with the sliders. Everything it fetches is under this
// folder.

import init, { AssetFiles, TryOn, kernelProbe, proceduralClips } from "./pkg/sartor_web.js";
import { Viewer } from "./viewer.js";

const $ = (id) => document.getElementById(id);
const MOTION_FPS = 30;
const WINDOW = 60;
// After a change of shape the arms are held anew for it in slices of at most this many
// milliseconds a display frame at 60 frames a second (a slice ends after the look that passes
// it; `sliceMs`).
const SETTLE_MS = 8;
// Where the display frames come slower (a slow device, or a browser whose drawing holds the
// main thread), a slice takes up to this share of the interval between them, up to
// SETTLE_MAX_MS: fewer frames show the old arms.
const SETTLE_SHARE = 0.25;
const SETTLE_MAX_MS = 20;

const GARMENT_COLOR = [0.16, 0.36, 0.7];

// The held limbs a release, a scrub or a new clip waits on are computed in a worker
// (limbs-worker.js) where the browser has them, off the thread that draws the frames; the page
// takes up its answers (TryOn.absorbArms). Without one, or once it failed, or with
// `?limbs=page` in the address, the page's own slices compute them (settleSome, seekSome).
// While a clip plays the worker also computes the held limbs of the frames ahead, so that the
// frames played compute none: a job of the next AHEAD_MAX frames whenever one of the next
// AHEAD_MIN lacks them (half a second and two at 30 frames a second).
const AHEAD_MIN = 15;
const AHEAD_MAX = 60;
const limbs = {
  worker: null,
  ready: false,
  enabled: true, // cleared, the page's slices compute (window.sartor.useLimbsWorker)
  busy: false, // the last job posted is not answered yet
  id: 0, // of the last job posted
  key: null, // what it was for (`epoch/scrub target`; limbsBusy)
  epoch: 0, // counts the changes of shape and clip that the page waits on
  fresh: null, // the key of the job just answered: the page's slice takes what is left of it
  jobs: 0, // answers taken up
  ahead: 0, // of them, of frames ahead
  stale: 0, // answers of a shape or clip left since
  ms: 0, // the worker's milliseconds in them
  pageMs: 0, // the page's milliseconds making the jobs and taking up the answers
  failure: null, // why the worker is no longer used
};

// The garment's post-processing (the strain limit and the collision post-process), most of a
// frame's work, is computed in a worker (post-worker.js) while a clip plays, where the browser
// has one: the page makes each frame up to it (TryOn.stepDeferred: the network, the skinning,
// the body), posts the job, and draws the frame when the answer comes back (TryOn.absorbPost;
// the page's own post-processing's garment, bit for bit), within the display frame after at
// most. A frame shown otherwise (a scrub, a change of shape or garment, the clip's start
// again) is post-processed on the page, as every frame is without a worker, once it failed,
// or with `?post=page` in the address.
const PRECISION = "f32";
const post = {
  worker: null,
  ready: false, // loaded with the garment worn
  enabled: true, // cleared, the page post-processes (window.sartor.usePostWorker)
  busy: false, // the last job posted is not answered yet
  id: 0, // of the last job posted
  jobPageMs: 0, // the page's milliseconds making that job
  answers: 0, // answers taken up (frames shown)
  stale: 0, // answers of a frame left since
  ms: 0, // the worker's milliseconds in its jobs
  failure: null, // why the worker is no longer used
  bodyFiles: [], // the body's files it was loaded with, by the runtime's names
};

const state = {
  tryOn: null,
  manifest: null,
  garment: null, // the manifest's entry of the garment model worn
  modelFiles: new Map(), // the garment models' files fetched so far, by name
  garmentMs: null, // the last change of garment, milliseconds (fetching not counted)
  playing: true,
  lastStep: 0,
  times: [], // [network, skinning, post, body, draw, arms, page] per frame, the last WINDOW
  framesStepped: 0,
  readyMs: null,
  errors: 0,
  previewFrame: 0, // the animation frame a slider's preview waits for (0: none)
  previews: 0,
  settling: false, // the arms being held anew for a new shape or clip (settleSome)
  motionShown: null, // the name of the motion the scrub bar is set up for
  seekTarget: null, // the frame the scrub bar asks for while its held arms are computed (seekSome)
  seekSlices: [0, 0], // of the last scrub: display frames with a slice, milliseconds in them
  settleLongestMs: 0, // the longest call of the slices so far
  lastTick: null, // the last display frame's time (tick)
  frameIntervalMs: 1000 / 60, // the interval between display frames, smoothed
};

function showError(message) {
  state.errors += 1;
  const box = $("error");
  box.textContent = message;
  box.hidden = false;
}

function clearError() {
  $("error").hidden = true;
}

/// Run `f`, showing any error on the page; returns whether it succeeded.
/// Show `what` failed with `e`.
function showFailure(what, e) {
  showError(`${what}: ${e && e.message ? e.message : e}`);
}

/// Run `f`; an error it throws is shown, and returns false. On success an error shown before is
/// cleared, unless `keepError` (a slice of work that does not answer the user's last action).
function guarded(what, f, keepError = false) {
  try {
    f();
    if (!keepError) clearError();
    return true;
  } catch (e) {
    showFailure(what, e);
    return false;
  }
}

async function fetchBytes(path) {
  const response = await fetch(path);
  if (!response.ok) throw new Error(`${path}: HTTP ${response.status}`);
  return new Uint8Array(await response.arrayBuffer());
}

const MODEL_FILES = ["model.json", "model.safetensors", "binding.json", "binding.safetensors"];
const BODY_FILES = ["model.json", "model.safetensors", "phenotype.json", "phenotype.safetensors", "tpose.json"];

/// The files of the manifest's garment model `model`, fetched once.
async function modelFiles(model) {
  if (!state.modelFiles.has(model.name)) {
    const path = (f) => `models/${model.name}/${f}`;
    const files = await Promise.all(MODEL_FILES.map((f) => fetchBytes(path(f))));
    state.modelFiles.set(model.name, files);
  }
  return state.modelFiles.get(model.name);
}

/// `files` (MODEL_FILES' bytes) by the runtime's names, added to `assets` (a new set if none).
function modelAssets(files, assets = new AssetFiles()) {
  MODEL_FILES.forEach((f, i) => assets.add(`model/${f}`, files[i]));
  return assets;
}

function showGarment() {
  const g = state.garment;
  const triangles = g.triangles.toLocaleString("en");
  $("status").textContent = `${g.garment}, ${triangles} triangles, post-process on`;
}

/// The manifest's garment model the page's address names (`?garment=default-8710`, which a
/// choice of garment writes, so that a link opens the page with it), else its first.
function linkedGarment(manifest) {
  return manifest.models.find((m) => m.name === linkedName()) || manifest.models[0];
}

/// The garment model's name in the page's address, or null.
function linkedName() {
  return new URLSearchParams(location.search).get("garment");
}

/// Wear the manifest's garment model `name` (fetched on first choice) on the shape, motion and
/// frame shown; the timings start anew, and the address names it. An error keeps the garment
/// worn.
async function chooseGarment(name) {
  const select = $("garment");
  const model = state.manifest.models.find((m) => m.name === name);
  select.disabled = true;
  const triangles = model.triangles.toLocaleString("en");
  $("status").textContent = `loading the ${triangles}-triangle garment…`;
  try {
    const files = await modelFiles(model);
    const t = state.tryOn;
    const start = performance.now();
    t.setGarment(modelAssets(files));
    state.garmentMs = performance.now() - start;
    state.garment = model;
    loadPostWorker(model, files);
    const url = new URL(location.href);
    url.searchParams.set("garment", name);
    history.replaceState(null, "", url);
    const n = t.garmentVertices().length / 3;
    state.viewer.setMesh("garment", t.garmentFaces(), n, GARMENT_COLOR);
    state.times = [];
    redraw();
    clearError();
  } catch (e) {
    showFailure(`garment ${name}`, e);
    select.value = state.garment.name;
  } finally {
    showGarment();
    select.disabled = false;
  }
}

function sliders() {
  return {
    gender: Number($("gender").value),
    heightM: Number($("height").value),
    weight: Number($("weight").value),
    muscle: Number($("muscle").value),
    ageYears: Number($("age").value),
  };
}

function showBetas(betas) {
  $("betas-out").textContent = Array.from(betas, (b) => b.toFixed(2)).join(", ");
  const [h, chest, waist, hips, kg] = state.tryOn.measurements();
  $("measured-out").textContent =
    `${h.toFixed(2)} m, chest ${(100 * chest).toFixed(1)}, waist ${(100 * waist).toFixed(1)}, ` +
    `hips ${(100 * hips).toFixed(1)} cm, ${kg.toFixed(0)} kg`;
}

function showSliders(s) {
  $("height-out").textContent = `${s.heightM.toFixed(2)} m`;
  $("age-out").textContent = `${s.ageYears} years`;
}

/// While a slider moves: the body and the garment in the slider's shape at the next display
/// frame (one preview a frame however many input events come), the arms held as for the shape
/// last set; the slider's release shows the shape and holds the arms anew (applyPhenotype).
function previewPhenotype() {
  showSliders(sliders());
  if (state.previewFrame) return;
  state.previewFrame = requestAnimationFrame(() => {
    state.previewFrame = 0;
    // The slider moves on: the arms are held anew at its release.
    state.settling = false;
    const s = sliders();
    guarded("body", () => {
      showBetas(state.tryOn.previewPhenotype(s.gender, s.heightM, s.weight, s.muscle, s.ageYears));
      state.previews += 1;
      redraw();
    });
  });
}

/// A slider's release: the shape shown at once (a preview), the arms then held anew for it a
/// slice a display frame (settleSome), so that the page never waits for the whole of it
/// (`TryOn::settle`; setting the shape at once takes some 200 ms in the browser).
function applyPhenotype() {
  if (state.previewFrame) {
    cancelAnimationFrame(state.previewFrame);
    state.previewFrame = 0;
  }
  const s = sliders();
  showSliders(s);
  guarded("body", () => {
    showBetas(state.tryOn.previewPhenotype(s.gender, s.heightM, s.weight, s.muscle, s.ageYears));
    settleAnew();
    redraw();
  });
}

/// The frames shown wait for their held limbs anew (a change of shape or clip): settleSome
/// takes them from the next display frame.
function settleAnew() {
  state.settling = true;
  limbs.epoch += 1;
}

/// A display frame's slice, milliseconds: SETTLE_SHARE of the interval between display frames,
/// from SETTLE_MS to SETTLE_MAX_MS.
function sliceMs() {
  return Math.min(SETTLE_MAX_MS, Math.max(SETTLE_MS, SETTLE_SHARE * state.frameIntervalMs));
}

/// One display frame's slice of work: `look` (a call that takes at most one look and returns
/// whether the work is done) until it is done or `sliceMs()` pass, then `finish` if done. Returns
/// whether the work is over: done, or failed (the error is shown; an error shown before stays).
function slice(what, look, finish) {
  const start = performance.now();
  let done = false;
  const ok = guarded(
    what,
    () => {
      const budget = sliceMs();
      while (!done && performance.now() - start < budget) done = look();
      if (done) finish();
    },
    true,
  );
  return { over: !ok || done, done: ok && done, ms: performance.now() - start };
}

/// The module worker `script`, its messages to `answer` and its failure to `failed`; null where
/// the address says `?<param>=page`, the browser has no workers, or it could not start
/// (`record.failure` then says why).
function startWorker(script, param, record, answer, failed) {
  const wanted = new URLSearchParams(location.search).get(param) !== "page";
  if (!wanted || typeof Worker === "undefined") return null;
  let worker;
  try {
    worker = new Worker(script, { type: "module" });
  } catch (e) {
    record.failure = String(e && e.message ? e.message : e);
    return null;
  }
  worker.onmessage = (event) => answer(event.data);
  worker.onerror = (event) => failed(event.message || "the worker failed");
  return worker;
}

/// Start the worker for the held limbs (the body's files, the manifest's arm clearance JSON).
function startLimbsWorker(bodyFiles, armClearance) {
  if (!armClearance) return;
  const worker = startWorker("limbs-worker.js", "limbs", limbs, limbsAnswer, limbsFailed);
  if (!worker) return;
  const files = BODY_FILES.map((f, i) => [`body/${f}`, bodyFiles[i]]);
  worker.postMessage({ load: { wasm: "pkg/sartor_web_bg.wasm", files, armClearance } });
  limbs.worker = worker;
}

function limbsAnswer(message) {
  if (message.ready) {
    limbs.ready = true;
    return;
  }
  if (message.error) {
    limbsFailed(message.error);
    return;
  }
  // A job is answered only if still in hand when done: an older answer crossed a newer job.
  if (message.id === limbs.id) limbs.busy = false;
  limbs.ms += message.ms;
  const start = performance.now();
  guarded(
    "arms",
    () => {
      if (state.tryOn.absorbArms(message.progress)) {
        limbs.jobs += 1;
        if (message.id === limbs.id && limbs.key === "ahead") limbs.ahead += 1;
        else if (message.id === limbs.id) limbs.fresh = limbs.key;
      } else {
        limbs.stale += 1;
      }
    },
    true,
  );
  limbs.pageMs += performance.now() - start;
}

/// The page's slices take over for good.
function limbsFailed(why) {
  limbs.failure = why;
  limbs.ready = false;
  limbs.busy = false;
  if (limbs.worker) limbs.worker.terminate();
  limbs.worker = null;
}

/// Whether the held limbs the page waits on now (a jump to `target`, a scrub's frame, or null)
/// are the worker's to compute: a job for them posted now or earlier whose answer is not back
/// (a job for something the page no longer waits on is replaced). False where there is no
/// worker or nothing to compute, or where an answer was just taken up (the page's slice then
/// computes what the frames played meanwhile added).
function limbsBusy(target) {
  if (!limbs.ready || !limbs.enabled) return false;
  const key = `${limbs.epoch}/${target}`;
  if (limbs.busy && limbs.key === key) return true;
  if (!limbs.busy && limbs.fresh === key) {
    limbs.fresh = null;
    return false;
  }
  return postJob(key, () => state.tryOn.armsJob(target === null ? undefined : target));
}

/// Post the job `makeJob` makes (none: undefined) for `key`; returns whether one was posted.
function postJob(key, makeJob) {
  const start = performance.now();
  let job;
  try {
    job = makeJob();
  } catch (e) {
    limbsFailed(String(e && e.message ? e.message : e));
    return false;
  }
  if (job) {
    limbs.busy = true;
    limbs.id += 1;
    limbs.key = key;
    limbs.worker.postMessage({ job, id: limbs.id }, [job.buffer]);
  }
  limbs.pageMs += performance.now() - start;
  return Boolean(job);
}

/// While a clip plays and the worker is idle: the held limbs of the frames ahead, where some of
/// them lack them (TryOn.armsAheadJob).
function limbsAhead() {
  if (!limbs.ready || !limbs.enabled || limbs.busy) return;
  postJob("ahead", () => state.tryOn.armsAheadJob(AHEAD_MIN, AHEAD_MAX));
}

/// One display frame's slice of holding the arms anew for the shape shown or a clip chosen
/// (`settle`); when they are held the frame shown is recomputed with them (the frame setting
/// the shape at once gives; a new clip's first frame) and drawn. Returns whether that happened.
/// Where the worker computes them, the frame only waits for its answer.
function settleSome() {
  if (limbsBusy(null)) return false;
  const t = state.tryOn;
  const look = () => {
    const call = performance.now();
    const done = t.settle(1);
    state.settleLongestMs = Math.max(state.settleLongestMs, performance.now() - call);
    return done;
  };
  const { over, done } = slice("arms", look, () => {});
  if (over) state.settling = false;
  if (done && t.motionName !== state.motionShown) motionChanged();
  else if (done) redraw();
  return done;
}

/// One display frame's slice of a scrub: the held arms of the frame the scrub bar asks for (and
/// of the warm-up frames before it, `prepareSeek`), then the jump to it. Returns whether the
/// jump happened (and was drawn).
function seekSome() {
  const t = state.tryOn;
  const target = state.seekTarget;
  if (limbsBusy(target)) return false;
  const { over, done, ms } = slice("seek", () => t.prepareSeek(target, 1), () => t.seek(target));
  state.seekSlices[0] += 1;
  state.seekSlices[1] += ms;
  if (over) state.seekTarget = null;
  if (done) redraw();
  return done;
}

function applyBetas() {
  const text = $("betas").value.trim();
  const values = text.split(/[\s,]+/).filter((t) => t.length > 0).map(Number);
  if (values.some((v) => !Number.isFinite(v))) {
    showError(`β: "${text}" is not a list of numbers`);
    return;
  }
  guarded("β", () => {
    showBetas(state.tryOn.previewBetas(new Float64Array(values)));
    settleAnew();
    redraw();
  });
}

// The body that has the measurements typed (any of them), with the gender, height and age of
// the sliders; weight and muscle are left to the fit (sartor_core::PhenotypeSpace::betas_for).
// Shown at once, the arms then held anew for it as on a slider's release (settleSome).
function fitMeasurements() {
  const s = sliders();
  const parts = [`gender=${s.gender}`, `height_m=${s.heightM}`, `age_years=${s.ageYears}`];
  for (const [id, key] of [["chest-cm", "chest_cm"], ["waist-cm", "waist_cm"],
    ["hips-cm", "hips_cm"], ["mass-kg", "mass_kg"]]) {
    const text = $(id).value.trim();
    if (text !== "") parts.push(`${key}=${text}`);
  }
  if (parts.length === 3) {
    showError("measurements: type a bust, waist, hip girth or a weight first");
    return;
  }
  const start = performance.now();
  guarded("measurements", () => {
    showBetas(state.tryOn.previewPhenotypeText(parts.join(", ")));
    state.fitMs = performance.now() - start;
    settleAnew();
    redraw();
  });
}

async function chooseMotion(value) {
  const t = state.tryOn;
  try {
    if (value.startsWith("procedural:")) {
      t.playProcedural(value.slice("procedural:".length));
    } else if (value === "walk") {
      t.playJson("walk.json", await fetchBytes("motions/walk.json"));
    } else if (value.startsWith("cmu/")) {
      const [json, tensors] = await Promise.all([
        fetchBytes(`motions/${value}.json`),
        fetchBytes(`motions/${value}.safetensors`),
      ]);
      t.playStored(value, json, tensors);
    }
    // It plays once its first frames' arms are held (settleSome).
    settleAnew();
    clearError();
  } catch (e) {
    showFailure(`motion ${value}`, e);
  }
}

async function playBvhFile(file) {
  try {
    const text = await file.text();
    state.tryOn.playBvh(file.name, text);
    settleAnew();
    clearError();
  } catch (e) {
    showFailure("dropped BVH", e);
  }
}

function motionChanged() {
  const t = state.tryOn;
  state.motionShown = t.motionName;
  $("scrub").max = String(t.nFrames - 1);
  state.times = [];
  redraw();
}

/// The times of the frame shown, with the drawing's and the page's own (`page`: what the frame
/// took on the page's thread, drawing included; not the worker's post-process).
function recordTimes(draw, page) {
  const [network, skinning, postMs, body, arms] = state.tryOn.times();
  state.times.push([network, skinning, postMs, body, draw, arms, page]);
  if (state.times.length > WINDOW) state.times.shift();
}

function meanTimes() {
  const n = state.times.length;
  const sum = [0, 0, 0, 0, 0, 0, 0];
  for (const t of state.times) for (let i = 0; i < 7; i++) sum[i] += t[i];
  return sum.map((s) => (n ? s / n : NaN));
}

function showTimes() {
  const [network, skinning, postMs, body, draw, arms, page] = meanTimes();
  const ms = (v) => (Number.isFinite(v) ? `${v.toFixed(2)} ms` : "–");
  $("t-network").textContent = ms(network);
  $("t-skinning").textContent = ms(skinning);
  $("t-post").textContent = ms(postMs) + (post.ready && post.enabled ? " (in its worker)" : "");
  const total = network + skinning + postMs;
  $("t-total").textContent = Number.isFinite(total) ? `${total.toFixed(2)} ms (${(1000 / total).toFixed(0)} frames/s)` : "–";
  $("t-body").textContent = ms(body);
  $("t-draw").textContent = ms(draw);
  $("t-arms").textContent = ms(arms);
  $("t-limbs").textContent = workerStatus(
    limbs, `${limbs.jobs} answers`, "starting", "the page computes it");
  $("t-page").textContent = ms(page);
  $("t-post-worker").textContent = workerStatus(
    post, `${post.answers} frames`, "loading", "the page post-processes");
}

/// What a worker (`record`: `post` or `limbs`) did so far (`done`: its count of answers, named),
/// or why there is none (`none`: where the page does its work).
function workerStatus(record, done, starting, none) {
  if (record.ready && record.enabled) {
    return `${done}, ${(record.ms / 1000).toFixed(2)} s of work`;
  }
  if (record.failure !== null) return `none: ${record.failure}`;
  if (record.worker !== null && !record.ready) return starting;
  return `none: ${none}`;
}

/// Upload the frame shown and draw it.
function redraw() {
  const t = state.tryOn;
  const body = t.bodyVertices();
  state.viewer.update("body", body);
  state.viewer.update("garment", t.garmentVertices());
  state.viewer.follow(body);
  const start = performance.now();
  state.viewer.draw();
  const draw = performance.now() - start;
  $("scrub").value = String(t.frame);
  const turn = t.armTurnDeg;
  $("frame-out").textContent =
    `${t.frame + 1} / ${t.nFrames}` + (turn > 0 ? ` (limbs turned ${turn.toFixed(0)}°)` : "") +
    (state.settling ? " (holding the limbs)" : "");
  return draw;
}

function tick(now) {
  const t = state.tryOn;
  // Smoothed over some ten frames; a gap of a second or more (a hidden tab) is not counted.
  const interval = state.lastTick === null ? Infinity : now - state.lastTick;
  if (interval < 1000) state.frameIntervalMs += 0.1 * (interval - state.frameIntervalMs);
  state.lastTick = now;
  // A display frame whose slice recomputed (and drew) the frame shown steps no further.
  if ((state.seekTarget !== null && seekSome()) || (state.settling && settleSome())) {
    requestAnimationFrame(tick);
    return;
  }
  // While the worker post-processes the frame stepped, the clip waits for it.
  if (state.playing && !post.busy && now - state.lastStep >= 1000 / MOTION_FPS - 1) {
    state.lastStep = now;
    stepFrame();
  } else if (!state.playing && state.viewer.needsDraw()) {
    // Paused: drawn only when the camera, a mesh or the canvas's size changed.
    state.viewer.draw();
  }
  requestAnimationFrame(tick);
}

/// Step the clip playing: the frame shown now, or once the worker's post-process answers.
function stepFrame() {
  const t = state.tryOn;
  const start = performance.now();
  let job;
  try {
    if (post.ready && post.enabled) job = t.stepDeferred();
    else t.step();
  } catch (e) {
    showFailure("frame", e);
    setPlaying(false);
    return;
  }
  const ms = performance.now() - start;
  if (job) {
    post.busy = true;
    post.id += 1;
    post.worker.postMessage({ job, id: post.id }, [job.buffer]);
    post.jobPageMs = performance.now() - start;
  } else {
    frameShown(ms);
  }
}

/// A frame stepped is shown, after `pageMs` of the page's own work on it.
function frameShown(pageMs) {
  state.framesStepped += 1;
  const start = performance.now();
  const draw = redraw();
  recordTimes(draw, pageMs + performance.now() - start);
  if (state.framesStepped % 10 === 0) showTimes();
  // (A frame the worker answers after a pause asks for none.)
  if (state.playing) limbsAhead();
}

/// Start the worker for the post-process: the garment model's files (`garment`: the manifest's
/// entry), the body's.
function startPostWorker(garment, garmentFiles, bodyFiles) {
  post.worker = startWorker("post-worker.js", "post", post, postAnswer, postFailed);
  loadPostWorker(garment, garmentFiles, bodyFiles);
}

/// Load the garment `garment` (its files `garmentFiles`) into the worker, with the body's
/// files (the first load) or those it holds: until it is loaded the page post-processes.
function loadPostWorker(garment, garmentFiles, bodyFiles = null) {
  if (!post.worker) return;
  post.ready = false;
  const files = MODEL_FILES.map((f, i) => [`model/${f}`, garmentFiles[i]]);
  if (bodyFiles) BODY_FILES.forEach((f, i) => files.push([`body/${f}`, bodyFiles[i]]));
  else files.push(...post.bodyFiles);
  post.bodyFiles = files.filter(([name]) => name.startsWith("body/"));
  post.worker.postMessage({
    load: { wasm: "pkg/sartor_web_bg.wasm", files, precision: PRECISION, garment: garment.name },
  });
}

function postAnswer(message) {
  if (message.ready) {
    // A load answered after a later change of garment is not the garment worn.
    post.ready = message.garment === state.garment.name;
    return;
  }
  if (message.error) {
    postFailed(message.error);
    return;
  }
  if (message.id === post.id) post.busy = false;
  post.ms += message.ms;
  const start = performance.now();
  let shown = false;
  guarded(
    "frame",
    () => {
      shown = state.tryOn.absorbPost(message.answer);
    },
    true,
  );
  if (shown) {
    post.answers += 1;
    frameShown(post.jobPageMs + performance.now() - start);
  } else {
    post.stale += 1;
  }
}

/// The page post-processes for good; a frame that waited on the worker is made anew.
function postFailed(why) {
  post.failure = why;
  post.ready = false;
  if (post.worker) post.worker.terminate();
  post.worker = null;
  if (post.busy) {
    post.busy = false;
    const t = state.tryOn;
    guarded("frame", () => {
      t.seek(t.frame);
      redraw();
    });
  }
}

function setPlaying(playing) {
  state.playing = playing;
  $("play").textContent = playing ? "pause" : "play";
}

/// Bytes the page transferred so far (Resource Timing), by kind.
function transferred() {
  const entries = performance.getEntriesByType("resource");
  const nav = performance.getEntriesByType("navigation")[0];
  let total = nav ? nav.transferSize : 0;
  let model = 0;
  let body = 0;
  let wasm = 0;
  for (const e of entries) {
    total += e.transferSize;
    if (e.name.includes("/models/")) model += e.transferSize;
    if (e.name.includes("/body/")) body += e.transferSize;
    if (e.name.endsWith(".wasm")) wasm += e.transferSize;
  }
  return { total, model, body, wasm };
}

/// Step `frames` frames back to back (the motion shown, from its start) and return the median
/// milliseconds of each stage (what the page can sustain, independent of the display rate), of
/// the page's part of a frame whose post-processing the worker computes (`deferredFrame`: the
/// network, the skinning, the body posed, the job's bytes), of a jump's
/// garment (`jump`), of a whole change of shape (`shape`), of the same change as a
/// slider's release makes it in slices (`releaseLongest`, the longest call of the preview and
/// the `settle(1)` calls, and `releaseWhole`, all of them) and of a preview while a slider
/// moves (`preview`).
function bench(frames = 120) {
  const t = state.tryOn;
  const was = state.playing;
  setPlaying(false);
  t.seek(0);
  const rows = [];
  for (let i = 0; i < frames; i++) {
    t.step();
    rows.push(t.times());
  }
  // The page's part of a frame whose post-process its worker computes (the job made, not
  // posted), over frames stepped above (their held limbs computed).
  t.seek(0);
  const deferred = medianMs(Math.min(30, frames), () => t.stepDeferred());
  // A jump's garment: seeks alternating between two frames the steps above went through (so
  // the arms' poses are kept), each running the GRU's warm-up and the frame shown.
  const targets = [Math.floor(frames / 3), Math.floor((2 * frames) / 3)].map((f) =>
    Math.min(f, t.nFrames - 1),
  );
  const jump = medianMs(10, (i) => t.seek(targets[i % 2]));
  // A change of shape, as a slider's release gives it: the body, the garment's shape caches,
  // the arms' poses anew for the frames the one shown depends on, and its jump. β₁ up by 0.5
  // and back, twice; the shape in use is restored.
  const betas = t.betas();
  const other = Float64Array.from(betas, (b, i) => (i === 0 ? b + 0.5 : b));
  const shape = medianMs(4, (i) => t.setBetas(i % 2 === 0 ? other : betas));
  // The same changes as a slider's release makes them: the preview, then `settle` a look at a
  // time (the page spreads these calls over display frames, `sliceMs()` each).
  const longest = [];
  const whole = [];
  for (let i = 0; i < 4; i++) {
    let most = 0;
    const call = (f) => {
      const start = performance.now();
      const result = f();
      most = Math.max(most, performance.now() - start);
      return result;
    };
    const start = performance.now();
    call(() => t.previewBetas(i % 2 === 0 ? other : betas));
    while (!call(() => t.settle(1)));
    longest.push(most);
    whole.push(performance.now() - start);
  }
  const middle = (v) => v.sort((a, b) => a - b)[Math.floor(v.length / 2)];
  // The same changes as a slider's move previews them (the arms as held for the shape last
  // set, the one in use): the last preview is of that shape, so it stays as it was set.
  const preview = medianMs(4, (i) => t.previewBetas(i % 2 === 0 ? other : betas));
  setPlaying(was);
  const median = (k) => {
    const v = rows.map((r) => r[k]).sort((a, b) => a - b);
    return v[Math.floor(v.length / 2)];
  };
  const totals = rows.map((r) => r[0] + r[1] + r[2]).sort((a, b) => a - b);
  return {
    frames,
    network: median(0),
    skinning: median(1),
    postProcess: median(2),
    body: median(3),
    arms: median(4),
    garmentFrame: totals[Math.floor(totals.length / 2)],
    deferredFrame: deferred,
    jump,
    shape,
    releaseLongest: middle(longest),
    releaseWhole: middle(whole),
    preview,
  };
}

/// The median milliseconds of `f(0)`, …, `f(n - 1)`.
function medianMs(n, f) {
  const ms = [];
  for (let i = 0; i < n; i++) {
    const start = performance.now();
    f(i);
    ms.push(performance.now() - start);
  }
  ms.sort((a, b) => a - b);
  return ms[Math.floor(n / 2)];
}

async function main() {
  state.viewer = new Viewer($("view"));
  // The garment model's files as soon as the manifest names it, beside the rest.
  const manifestRead = fetchBytes("manifest.json").then((b) =>
    JSON.parse(new TextDecoder().decode(b)),
  );
  const [manifest, garmentFiles, , ...bodyFiles] = await Promise.all([
    manifestRead,
    manifestRead.then((m) => modelFiles(linkedGarment(m))),
    init({ module_or_path: "pkg/sartor_web_bg.wasm" }),
    ...BODY_FILES.map((f) => fetchBytes(`body/${f}`)),
  ]);
  state.manifest = manifest;
  state.garment = linkedGarment(manifest);

  const assets = modelAssets(garmentFiles);
  BODY_FILES.forEach((f, i) => assets.add(`body/${f}`, bodyFiles[i]));
  // The arms held out of the torso as the model's training motions held them.
  const armClearance = manifest.arm_clearance ? JSON.stringify(manifest.arm_clearance) : undefined;
  const t = TryOn.load(assets, PRECISION, true, armClearance);
  state.tryOn = t;
  startLimbsWorker(bodyFiles, armClearance);
  startPostWorker(state.garment, garmentFiles, bodyFiles);
  state.viewer.setMesh("body", t.bodyFaces(), t.bodyVertices().length / 3, [0.86, 0.72, 0.62]);
  state.viewer.setMesh("garment", t.garmentFaces(), t.garmentVertices().length / 3, GARMENT_COLOR);
  const body = t.bodyVertices();
  let floorY = Infinity;
  for (let i = 1; i < body.length; i += 3) floorY = Math.min(floorY, body[i]);
  state.viewer.setFloor(floorY - 0.005, 0, 0);

  // Motions: the manifest's procedural clips (all known to the runtime), the walk, CMU clips.
  const known = new Set(proceduralClips());
  const select = $("motion");
  const add = (value, label) => {
    const option = document.createElement("option");
    option.value = value;
    option.textContent = label;
    select.append(option);
  };
  for (const name of manifest.procedural) {
    if (known.has(name)) add(`procedural:${name}`, `${name} (procedural)`);
  }
  add("walk", "walk (MakeHuman walk cycle)");
  for (const clip of manifest.clips) add(clip.name, clip.label);

  const mb = (b) => `${(b / 1e6).toFixed(2)} MB`;
  const garments = $("garment");
  for (const m of manifest.models) {
    const option = document.createElement("option");
    option.value = m.name;
    option.textContent = `${m.triangles.toLocaleString("en")} triangles (${mb(m.page_bytes)})`;
    garments.append(option);
  }
  garments.value = state.garment.name;

  applyPhenotype();
  await chooseMotion(select.value);

  for (const id of ["gender", "height", "weight", "muscle", "age"]) {
    $(id).addEventListener("change", applyPhenotype);
    $(id).addEventListener("input", previewPhenotype);
  }
  $("apply-betas").addEventListener("click", applyBetas);
  $("fit-measurements").addEventListener("click", fitMeasurements);
  select.addEventListener("change", () => chooseMotion(select.value));
  garments.addEventListener("change", () => chooseGarment(garments.value));
  $("bvh").addEventListener("change", (e) => {
    if (e.target.files.length > 0) playBvhFile(e.target.files[0]);
  });
  document.addEventListener("dragover", (e) => e.preventDefault());
  document.addEventListener("drop", (e) => {
    e.preventDefault();
    const file = e.dataTransfer.files[0];
    if (file) playBvhFile(file);
  });
  $("play").addEventListener("click", () => setPlaying(!state.playing));
  // The jump waits for its frame's held arms, computed a slice a display frame (seekSome).
  $("scrub").addEventListener("input", () => {
    setPlaying(false);
    state.seekTarget = Number($("scrub").value);
    state.seekSlices = [0, 0];
    $("frame-out").textContent = `${state.seekTarget + 1} / ${t.nFrames} (holding the limbs)`;
  });
  $("garment-panel").disabled = false;
  $("body-panel").disabled = false;
  $("motion-panel").disabled = false;

  state.readyMs = performance.now();
  const bytes = transferred();
  const g = state.garment;
  $("loaded").textContent =
    `usable ${(state.readyMs / 1000).toFixed(2)} s after navigation; transferred ${mb(bytes.total)} ` +
    `(model ${mb(bytes.model)} with ${g.storage}; f32 would be ${mb(g.f32_bytes)}; ` +
    `body ${mb(bytes.body)}, WebAssembly ${mb(bytes.wasm)})`;
  showGarment();
  // (After the first motion's load, which clears the error box.)
  const wanted = linkedName();
  if (wanted !== null && wanted !== state.garment.name) {
    const offered = manifest.models.map((m) => m.name).join(", ");
    showError(`garment "${wanted}" in the address: no such model (offered: ${offered})`);
  }
  document.body.dataset.ready = "true";
  requestAnimationFrame(tick);
}

// What the browser test (and a curious reader's console) can look at.
window.sartor = {
  state,
  limbs,
  // Whether the worker computes the held limbs (true: where it runs); false: the page's slices.
  useLimbsWorker: (on) => {
    limbs.enabled = on;
  },
  post,
  stepFrame,
  // Whether the worker post-processes the frames played (true: where it runs); false: the page.
  // The timings start anew.
  usePostWorker: (on) => {
    post.enabled = on;
    state.times = [];
  },
  ready: () => state.readyMs !== null,
  garment: () => Array.from(state.tryOn.garmentVertices()),
  meanTimes,
  transferred,
  bench,
  setPlaying,
  chooseGarment,
  kernelProbe: () => Array.from(kernelProbe()),
};

main().catch((e) => {
  showFailure("loading", e);
  $("status").textContent = "failed to load";
});
