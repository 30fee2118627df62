// The try-on page's worker for the garment's post-process: its own WebAssembly runtime with the
// garment model and the body (sartor-web's PostWorker). The page posts `load` (again for
// another garment), then jobs (the bytes of TryOn.stepDeferred, each with an id), and takes up
// each answer with TryOn.absorbPost; pushing the garment out of the body here, most of a
// frame's work, keeps it off the thread that draws the page's frames. Messages are taken in
// order, so a job made after a change of garment meets the garment loaded for it.

import init, { AssetFiles, PostWorker } from "./pkg/sartor_web.js";

let post = null;
let started = null; // the WebAssembly runtime's initialisation, once

function failed(id, e) {
  self.postMessage({ id, error: e && e.message ? e.message : String(e) });
}

self.onmessage = async (event) => {
  const message = event.data;
  if (message.load) {
    try {
      const { wasm, files, precision } = message.load;
      started ??= init({ module_or_path: wasm });
      await started;
      const assets = new AssetFiles();
      for (const [name, bytes] of files) assets.add(name, bytes);
      post = PostWorker.load(assets, precision);
      self.postMessage({ ready: true, garment: message.load.garment });
    } catch (e) {
      failed(null, e);
    }
  } else if (message.job) {
    try {
      const start = performance.now();
      const answer = post.run(message.job);
      const ms = performance.now() - start;
      self.postMessage({ id: message.id, answer, ms }, [answer.buffer]);
    } catch (e) {
      failed(message.id, e);
    }
  }
};
