// The jobs panel: the datasets on the server (uploaded, captured, aligned) with what can be
// done with each (build, align, look at the alignment pictures), uploading a capture zip,
// queueing a build job, following its progress, and handing the new motion space to the picker
// when the job succeeds (docs/rest.md: datasets, jobs).
import { api, setToken, ApiError } from "./api.js";
import { openDialog } from "./dialogs.js";

const MEASURES = ["speed", "turn_rate", "jump_height", "jump_distance", "reach_height"];
const ACTIVE = ["queued", "running"];
const NAME = /^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$/;
const PICTURES = {
  "similarity.png": "shape dissimilarity between every pair of frames (fig. 1c)",
  "tree.png": "the shape similarity tree the alignment follows (fig. 1d)",
  "aligned_pattern.png": "a pattern fixed on the root mesh, carried to every frame (fig. 2)",
};

const $ = (id) => document.getElementById(id);

function el(tag, props = {}, ...children) {
  const node = Object.assign(document.createElement(tag), props);
  node.append(...children);
  return node;
}

/** A dataset name from a file name: "My capture (2).zip" -> "My_capture_2". */
function unstructured(dataset) {
  return dataset.sequences.filter((seq) => seq.unstructured_frames > 0);
}

export function datasetName(fileName) {
  const stem = fileName.replace(/\.zip$/i, "").replace(/[^A-Za-z0-9_.-]+/g, "_").replace(/^[^A-Za-z0-9]+/, "");
  return stem.slice(0, 128) || "dataset";
}

/** POST a zip with upload progress (fetch cannot report it). Resolves to the dataset record. */
function uploadZip(file, query, token, onProgress) {
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    xhr.open("POST", `/v1/datasets?${new URLSearchParams(query)}`);
    xhr.setRequestHeader("Content-Type", "application/zip");
    if (token) xhr.setRequestHeader("Authorization", `Bearer ${token}`);
    xhr.upload.onprogress = (event) => event.lengthComputable && onProgress(event.loaded / event.total);
    xhr.onload = () => {
      let body = null;
      try { body = JSON.parse(xhr.responseText); } catch { body = { detail: xhr.responseText }; }
      if (xhr.status === 201) resolve(body);
      else reject(new ApiError(xhr.status, typeof body?.detail === "string" ? body.detail : `upload failed: HTTP ${xhr.status}`));
    };
    xhr.onerror = () => reject(new ApiError(0, "upload failed: the server could not be reached"));
    xhr.send(file);
  });
}

export class JobsPanel {
  constructor({ onSpaceReady, say }) {
    this.onSpaceReady = onSpaceReady;
    this.say = say;
    this.datasets = [];
    this.jobs = [];
    this.watching = new Set();   // jobs seen queued/running here: announce when they finish
    this.mine = new Set();       // jobs started from this page
    this.timer = null;
  }

  start() {
    $("token").addEventListener("input", (e) => setToken(e.target.value));
    $("upload-file").addEventListener("change", (e) => {
      const file = e.target.files[0];
      if (file && !$("upload-name").value) $("upload-name").value = datasetName(file.name);
    });
    $("upload-form").addEventListener("submit", (e) => { e.preventDefault(); this.upload(); });
    $("build-form").addEventListener("submit", (e) => { e.preventDefault(); this.build(); });
    $("build-dataset").addEventListener("change", () => this.showDataset());
    $("align-button").addEventListener("click", () => this.align());
    $("datasets").replaceChildren(el("li", { className: "empty" }, "…"));
    $("build-layout").addEventListener("change", () => this.showLayout());
    $("build-measures").replaceChildren(...MEASURES.map((m) => el("label", {},
      el("input", { type: "checkbox", value: m, checked: m === "speed" }), ` ${m.replace("_", " ")}`)));
    this.refreshDatasets();
    this.poll();
  }

  // ------------------------------------------------------------ upload

  async upload() {
    const file = $("upload-file").files[0];
    const name = $("upload-name").value.trim() || (file && datasetName(file.name));
    if (!file) return this.say("Choose a zip file to upload first.", "warn");
    if (!NAME.test(name)) return this.say(`Dataset name ${JSON.stringify(name)}: use letters, digits, '_', '-', '.'.`, "error");
    const bar = $("upload-progress");
    bar.hidden = false;
    bar.value = 0;
    $("upload-button").disabled = true;
    try {
      const query = { name, fps: $("upload-fps").value || "30", cyclic: String($("upload-cyclic").checked) };
      const dataset = await uploadZip(file, query, $("token").value, (f) => { bar.value = f; });
      this.say(`Uploaded ${dataset.name}: ${dataset.sequences.length} sequences, ${dataset.frames} frames.`, "info", 6000);
      await this.refreshDatasets(dataset.name);
    } catch (err) {
      this.say(`Upload failed (${err.status || "network"}): ${err.message}`, "error", 10000);
    } finally {
      bar.hidden = true;
      $("upload-button").disabled = false;
    }
  }

  // ------------------------------------------------------------ build form

  async refreshDatasets(select) {
    try {
      this.datasets = (await api.request("GET", "/datasets")).datasets;
    } catch {
      return;
    }
    const usable = this.datasets.filter((d) => d.buildable.length >= 2 || unstructured(d).length > 0);
    this.renderDatasets();
    $("build-form").hidden = usable.length === 0;
    const picker = $("build-dataset");
    const keep = select || picker.value;
    picker.replaceChildren(...usable.map((d) => new Option(
      d.buildable.length >= 2 ? `${d.name} (${d.buildable.length} sequences)` : `${d.name} (unstructured)`, d.name)));
    if (usable.some((d) => d.name === keep)) picker.value = keep;
    this.showDataset();
  }

  /** One row per dataset: name, kind, sequences and frames; Build, Align, Pictures. */
  renderDatasets() {
    const list = $("datasets");
    if (this.datasets.length === 0) {
      list.replaceChildren(el("li", { className: "empty" }, "none yet: upload a capture below"));
      return;
    }
    list.replaceChildren(...this.datasets.map((d) => {
      const head = el("div", { className: "dataset-head" }, el("span", { className: "dataset-name", title: d.name }, d.name),
        el("span", { className: "dataset-kind" }, `${d.kind} · ${d.sequences.length} sequences · ${d.frames} frames`));
      const buttons = el("div", { className: "buttons" });
      const button = (label, action, title) => {
        const b = el("button", { type: "button", textContent: label, title });
        b.dataset.action = label.toLowerCase();
        b.addEventListener("click", action);
        buttons.append(b);
      };
      if (d.buildable.length >= 2) {
        button("Build", () => this.chooseForBuild(d.name), `build a motion space from ${d.name}'s ${d.buildable.length} sequences`);
      }
      if (unstructured(d).length > 0) {
        button("Align", () => this.align(d.name), `align ${unstructured(d).length} unstructured sequences into one mesh structure`);
      }
      if (d.pictures?.length) {
        button("Pictures", () => this.openPictures(`Alignment of ${d.name}`, d.pictures.map((p) => ({
          src: `/v1/datasets/${encodeURIComponent(d.name)}/pictures/${p}`, caption: PICTURES[p] ?? p }))),
        "the similarity matrix, the tree and the aligned pattern");
      }
      const item = el("li", {}, head, buttons);
      item.dataset.name = d.name;
      return item;
    }));
  }

  /** The pictures dialog: [{src, caption}] under a title. */
  openPictures(title, pictures) {
    $("pictures-title").textContent = title;
    $("pictures").replaceChildren(...pictures.map(({ src, caption }) =>
      el("figure", {}, el("img", { src, alt: caption }), el("figcaption", { textContent: caption }))));
    openDialog("pictures-dialog", "pictures-close");
  }

  /** Show the build form for a dataset and move focus there. */
  chooseForBuild(name) {
    $("build-dataset").value = name;
    this.showDataset();
    $("build-form").scrollIntoView({ block: "nearest" });
    $("build-dataset").focus();
  }

  showDataset() {
    const dataset = this.datasets.find((d) => d.name === $("build-dataset").value);
    if (!dataset) return;
    const buildable = dataset.buildable.length >= 2;
    $("build-options").hidden = !buildable;
    $("build-align").hidden = buildable;
    $("build-sources").replaceChildren(...dataset.buildable.map((name) => el("label", {},
      el("input", { type: "checkbox", value: name, checked: true }), ` ${name}`)));
    for (const id of ["build-left", "build-right"]) {
      $(id).replaceChildren(...dataset.buildable.map((name) => new Option(name, name)));
    }
    $("build-space").value = dataset.name;
    this.showLayout();
  }

  showLayout() {
    $("build-fan").hidden = $("build-layout").value !== "fan";
  }

  buildRequest() {
    const sources = [...$("build-sources").querySelectorAll("input:checked")].map((i) => i.value);
    const measures = [...$("build-measures").querySelectorAll("input:checked")].map((i) => i.value);
    const layout = $("build-layout").value;
    const parameters = { layout, measures };
    if (layout === "chain") parameters.chain = sources;
    if (layout === "grid") parameters.corners = sources;
    if (layout === "fan") {
      parameters.left = $("build-left").value;
      parameters.right = $("build-right").value;
      parameters.chain = sources.filter((s) => s !== parameters.left && s !== parameters.right);
    }
    const spec = { sources, parameters, epsilon_mm: Number($("build-epsilon").value) || 5 };
    if ($("build-phases").value) spec.phases = Number($("build-phases").value);
    return { kind: "build", dataset: $("build-dataset").value, space: $("build-space").value.trim(), spec,
      replace: $("build-replace").checked };
  }

  async build() {
    const request = this.buildRequest();
    if (!NAME.test(request.space)) return this.say("Give the space a name (letters, digits, '_', '-', '.').", "error");
    if (request.spec.sources.length < 2) return this.say("A motion space needs at least two source sequences.", "error");
    $("build-button").disabled = true;
    try {
      const job = await api.request("POST", "/jobs", request);
      this.watching.add(job.id);
      this.mine.add(job.id);
      this.say(`Build of ${request.space} queued (job ${job.id.slice(0, 8)}).`, "info");
      this.poll();
    } catch (err) {
      this.say(`Build refused (${err.status || "network"}): ${err.message}`, "error", 10000);
    } finally {
      $("build-button").disabled = false;
    }
  }

  async align(name) {
    const dataset = name ?? $("build-dataset").value;
    const request = { kind: "align", datasets: [dataset], output: `${dataset}_aligned`.slice(0, 128) };
    try {
      const job = await api.request("POST", "/jobs", request);
      this.say(`Alignment of ${dataset} queued (writes ${request.output}); build from it when it is done.`, "info", 8000);
      this.watching.add(job.id);
      this.poll();
    } catch (err) {
      this.say(`Alignment refused (${err.status || "network"}): ${err.message}`, "error", 10000);
    }
  }

  // ------------------------------------------------------------ job list

  async poll() {
    clearTimeout(this.timer);
    let active = false;
    try {
      this.jobs = (await api.request("GET", "/jobs?limit=8")).jobs;
      for (const job of this.jobs) {
        if (ACTIVE.includes(job.status)) {
          active = true;
          if (job.kind === "build") this.watching.add(job.id);
        } else if (this.watching.has(job.id)) {
          this.watching.delete(job.id);
          this.finished(job);
        }
      }
      this.renderJobs();
    } catch {
      // the server is down or restarting: try again later
    }
    this.timer = setTimeout(() => this.poll(), active ? 700 : 4000);
  }

  finished(job) {
    const space = job.params?.space;
    if (job.status === "succeeded" && job.kind === "build" && space) {
      this.onSpaceReady(space, this.mine.has(job.id));  // select it only if it was started here
    } else if (job.status === "succeeded" && job.kind !== "build") {
      this.say(`${job.kind} job done: dataset ${job.params?.output ?? job.params?.dataset} is ready.`, "info", 8000);
      this.refreshDatasets(job.params?.output);
      return;
    } else if (job.status === "failed") {
      this.say(`Job ${job.id.slice(0, 8)} failed: ${job.error}`, "error", 12000);
    }
    if (job.kind !== "build") this.refreshDatasets();
  }

  renderJobs() {
    $("job-list").replaceChildren(...this.jobs.map((job) => {
      const target = job.params?.space ?? job.params?.output ?? job.params?.dataset ?? "";
      const status = el("span", { className: `job-status ${job.status}` },
        job.status === "running" ? `${job.stage} · ${Math.round(job.progress * 100)}%` : job.status);
      const head = el("div", { className: "job-head" }, el("span", {}, `${job.kind} ${target}`), status);
      const bar = el("progress", { max: 1, value: job.status === "succeeded" ? 1 : job.progress });
      const item = el("li", { id: `job-${job.id}` }, head, bar);
      item.dataset.status = job.status;
      const detail = job.error || (ACTIVE.includes(job.status) ? job.log.at(-1) : "") || "";
      if (detail) item.append(el("div", { className: "job-detail" }, detail));
      if (ACTIVE.includes(job.status)) {
        const cancel = el("button", { type: "button", textContent: "Cancel" });
        cancel.addEventListener("click", async () => {
          try {
            await api.request("POST", `/jobs/${job.id}/cancel`);
            this.poll();
          } catch (err) {
            this.say(`Cancel failed: ${err.message}`, "error");
          }
        });
        item.append(cancel);
      }
      return item;
    }));
  }
}
