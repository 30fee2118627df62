// The try-on page's worker for the held limbs: its own WebAssembly runtime with the body alone
// (sartor-web's LimbsWorker). The page posts `load` once, then jobs (the bytes of TryOn.armsJob,
// each with an id), and takes up each answer with TryOn.absorbArms; computing the looks here
// keeps them off the thread that draws the page's frames. A job is computed a few looks a step,
// each step a task of its own, so that a newer job (a scrub that moved on, a clip chosen) takes
// over between steps; only the job in hand when the work is done is answered.

import init, { AssetFiles, LimbsWorker } from "./pkg/sartor_web.js";

// Looks a step: some 5 to 10 ms in the browser.
const LOOKS_PER_STEP = 4;

let limbs = null;
let job = null; // the job in hand: { id, ms }
let scheduled = false; // a step posted and not run yet
const steps = new MessageChannel();
steps.port1.onmessage = () => {
  scheduled = false;
  step();
};

function schedule() {
  if (scheduled) return;
  scheduled = true;
  steps.port2.postMessage(null);
}

function failed(id, e) {
  self.postMessage({ id, error: e && e.message ? e.message : String(e) });
}

function step() {
  if (!job) return;
  const start = performance.now();
  try {
    const done = limbs.work(LOOKS_PER_STEP);
    job.ms += performance.now() - start;
    if (done) {
      const progress = limbs.answer();
      self.postMessage({ id: job.id, progress, ms: job.ms }, [progress.buffer]);
      job = null;
    } else {
      schedule();
    }
  } catch (e) {
    failed(job.id, e);
    job = null;
  }
}

self.onmessage = async (event) => {
  const message = event.data;
  if (message.load) {
    try {
      const { wasm, files, armClearance } = message.load;
      await init({ module_or_path: wasm });
      const assets = new AssetFiles();
      for (const [name, bytes] of files) assets.add(name, bytes);
      limbs = LimbsWorker.load(assets, armClearance);
      self.postMessage({ ready: true });
    } catch (e) {
      failed(null, e);
    }
  } else if (message.job) {
    const start = performance.now();
    try {
      limbs.begin(message.job);
    } catch (e) {
      failed(message.id, e);
      job = null;
      return;
    }
    job = { id: message.id, ms: performance.now() - start };
    schedule();
  }
};
