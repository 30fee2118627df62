// A small WebGL2 viewer: the body and the garment as triangle meshes with flat Lambert shading
// (normals from screen-space derivatives, so no normals are computed per frame), a floor, and
// an orbit camera that follows the body. No library.

const VERTEX = `#version 300 es
in vec3 position;
uniform mat4 viewProjection;
out vec3 world;
void main() {
  world = position;
  gl_Position = viewProjection * vec4(position, 1.0);
}`;

const FRAGMENT = `#version 300 es
precision highp float;
in vec3 world;
uniform vec3 color;
uniform vec3 eye;
out vec4 outColor;
void main() {
  vec3 n = normalize(cross(dFdx(world), dFdy(world)));
  vec3 toEye = normalize(eye - world);
  if (dot(n, toEye) < 0.0) n = -n;
  vec3 key = normalize(vec3(0.4, 0.8, 0.6));
  float light = 0.35 + 0.45 * max(dot(n, toEye), 0.0) + 0.3 * max(dot(n, key), 0.0);
  outColor = vec4(color * light, 1.0);
}`;

function compile(gl, type, source) {
  const shader = gl.createShader(type);
  gl.shaderSource(shader, source);
  gl.compileShader(shader);
  if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) {
    throw new Error(`shader: ${gl.getShaderInfoLog(shader)}`);
  }
  return shader;
}

class Mesh {
  constructor(gl, program, faces, vertexCount, color) {
    this.gl = gl;
    this.color = color;
    this.count = faces.length;
    this.vao = gl.createVertexArray();
    gl.bindVertexArray(this.vao);
    this.positions = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, this.positions);
    gl.bufferData(gl.ARRAY_BUFFER, vertexCount * 12, gl.DYNAMIC_DRAW);
    const at = gl.getAttribLocation(program, "position");
    gl.enableVertexAttribArray(at);
    gl.vertexAttribPointer(at, 3, gl.FLOAT, false, 0, 0);
    this.indices = gl.createBuffer();
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, this.indices);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, faces, gl.STATIC_DRAW);
    gl.bindVertexArray(null);
  }

  /// Free the GL objects (the mesh is replaced).
  dispose() {
    const gl = this.gl;
    gl.deleteVertexArray(this.vao);
    gl.deleteBuffer(this.positions);
    gl.deleteBuffer(this.indices);
  }

  update(vertices) {
    const gl = this.gl;
    gl.bindBuffer(gl.ARRAY_BUFFER, this.positions);
    gl.bufferSubData(gl.ARRAY_BUFFER, 0, vertices);
  }

  draw(colorAt) {
    const gl = this.gl;
    gl.uniform3fv(colorAt, this.color);
    gl.bindVertexArray(this.vao);
    gl.drawElements(gl.TRIANGLES, this.count, gl.UNSIGNED_INT, 0);
  }
}

function perspective(fovY, aspect, near, far) {
  const f = 1 / Math.tan(fovY / 2);
  const d = 1 / (near - far);
  return [f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * d, -1, 0, 0, 2 * far * near * d, 0];
}

function lookAt(eye, target, up) {
  const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
  const norm = (a) => {
    const l = Math.hypot(a[0], a[1], a[2]);
    return [a[0] / l, a[1] / l, a[2] / l];
  };
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const z = norm(sub(eye, target));
  const x = norm(cross(up, z));
  const y = cross(z, x);
  return [x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0, -dot(x, eye), -dot(y, eye), -dot(z, eye), 1];
}

function multiply(a, b) {
  const out = new Array(16).fill(0);
  for (let c = 0; c < 4; c++) {
    for (let r = 0; r < 4; r++) {
      for (let k = 0; k < 4; k++) out[c * 4 + r] += a[k * 4 + r] * b[c * 4 + k];
    }
  }
  return out;
}

export class Viewer {
  constructor(canvas) {
    const gl = canvas.getContext("webgl2", { antialias: true, preserveDrawingBuffer: true });
    if (!gl) throw new Error("this browser has no WebGL2");
    this.gl = gl;
    this.canvas = canvas;
    const program = gl.createProgram();
    gl.attachShader(program, compile(gl, gl.VERTEX_SHADER, VERTEX));
    gl.attachShader(program, compile(gl, gl.FRAGMENT_SHADER, FRAGMENT));
    gl.linkProgram(program);
    if (!gl.getProgramParameter(program, gl.LINK_STATUS)) {
      throw new Error(`shader program: ${gl.getProgramInfoLog(program)}`);
    }
    this.program = program;
    this.at = {
      viewProjection: gl.getUniformLocation(program, "viewProjection"),
      color: gl.getUniformLocation(program, "color"),
      eye: gl.getUniformLocation(program, "eye"),
    };
    this.meshes = {};
    this.azimuth = 0.45; // radians about +Y from +Z (the body's front)
    this.elevation = 0.12;
    this.zoom = 1;
    this.target = null;
    this.floorY = 0;
    // Whether what is shown changed since the last draw (a mesh, the camera); `needsDraw`.
    this.stale = true;
    this.draws = 0;
    this.installControls();
  }

  installControls() {
    // The pointers down on the view: one turns the camera round the body, two pinch to zoom
    // (a phone), the wheel zooms too.
    const down = new Map();
    let pinch = null; // the two pointers' distance when last seen
    const spread = () => {
      const [a, b] = [...down.values()];
      return Math.hypot(a.x - b.x, a.y - b.y);
    };
    this.canvas.addEventListener("pointerdown", (e) => {
      down.set(e.pointerId, { x: e.clientX, y: e.clientY });
      // Capture keeps a drag that leaves the view; a pointer the browser does not know as
      // active (a synthetic one) cannot be captured, and needs not be.
      try {
        this.canvas.setPointerCapture(e.pointerId);
      } catch {}
      pinch = down.size === 2 ? spread() : null;
    });
    const up = (e) => {
      down.delete(e.pointerId);
      pinch = down.size === 2 ? spread() : null;
    };
    this.canvas.addEventListener("pointerup", up);
    this.canvas.addEventListener("pointercancel", up);
    this.canvas.addEventListener("pointermove", (e) => {
      const last = down.get(e.pointerId);
      if (!last) return;
      const now = { x: e.clientX, y: e.clientY };
      down.set(e.pointerId, now);
      this.stale = true;
      if (down.size === 1) {
        this.azimuth -= (now.x - last.x) * 0.01;
        this.elevation = Math.max(-1.2, Math.min(1.2, this.elevation + (now.y - last.y) * 0.01));
      } else if (down.size === 2 && pinch) {
        // Fingers apart bring the camera closer, together take it back.
        const d = spread();
        if (d > 0) this.zoomBy(pinch / d);
        pinch = d;
      }
    });
    this.canvas.addEventListener(
      "wheel",
      (e) => {
        e.preventDefault();
        this.zoomBy(Math.exp(e.deltaY * 0.001));
      },
      { passive: false },
    );
  }

  /// The camera's distance times `factor`, within 0.3 to 4 times the framing's.
  zoomBy(factor) {
    this.zoom = Math.max(0.3, Math.min(4, this.zoom * factor));
    this.stale = true;
  }

  /// Whether a draw would show something new: a mesh or the camera changed since the last
  /// one, or the canvas's size on the page did (a paused page draws only then).
  needsDraw() {
    const ratio = window.devicePixelRatio || 1;
    const c = this.canvas;
    return (
      this.stale ||
      c.width !== Math.round(c.clientWidth * ratio) ||
      c.height !== Math.round(c.clientHeight * ratio)
    );
  }

  /// (Re)create a mesh: `faces` a Uint32Array, `vertexCount` its vertices, `color` [r, g, b].
  setMesh(name, faces, vertexCount, color) {
    if (this.meshes[name]) this.meshes[name].dispose();
    this.meshes[name] = new Mesh(this.gl, this.program, faces, vertexCount, color);
    this.stale = true;
  }

  setFloor(y, centerX, centerZ) {
    const s = 2.5;
    const v = new Float32Array([
      centerX - s, y, centerZ - s, centerX + s, y, centerZ - s,
      centerX + s, y, centerZ + s, centerX - s, y, centerZ + s,
    ]);
    this.setMesh("floor", new Uint32Array([0, 2, 1, 0, 3, 2]), 4, [0.55, 0.56, 0.58]);
    this.meshes.floor.update(v);
  }

  update(name, vertices) {
    this.meshes[name].update(vertices);
    this.stale = true;
  }

  /// Follow the body: its bounding box centre, eased, and its height for the distance.
  follow(bodyVertices) {
    let lo = [Infinity, Infinity, Infinity];
    let hi = [-Infinity, -Infinity, -Infinity];
    for (let i = 0; i < bodyVertices.length; i += 3) {
      for (let c = 0; c < 3; c++) {
        const v = bodyVertices[i + c];
        if (v < lo[c]) lo[c] = v;
        if (v > hi[c]) hi[c] = v;
      }
    }
    const center = [0, 1, 2].map((c) => 0.5 * (lo[c] + hi[c]));
    const height = Math.max(hi[1] - lo[1], 0.5);
    this.stale = true;
    if (!this.target) {
      this.target = center;
      this.height = height;
    } else {
      for (let c = 0; c < 3; c++) this.target[c] += 0.15 * (center[c] - this.target[c]);
      this.height += 0.15 * (height - this.height);
    }
  }

  draw() {
    this.stale = false;
    this.draws += 1;
    const gl = this.gl;
    const canvas = this.canvas;
    const ratio = window.devicePixelRatio || 1;
    const w = Math.round(canvas.clientWidth * ratio);
    const h = Math.round(canvas.clientHeight * ratio);
    if (canvas.width !== w || canvas.height !== h) {
      canvas.width = w;
      canvas.height = h;
    }
    gl.viewport(0, 0, w, h);
    gl.clearColor(0.93, 0.94, 0.96, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    if (!this.target) return;
    const fov = (35 * Math.PI) / 180;
    const distance = (this.zoom * 0.8 * this.height) / Math.tan(fov / 2);
    const t = this.target;
    const eye = [
      t[0] + distance * Math.cos(this.elevation) * Math.sin(this.azimuth),
      t[1] + distance * Math.sin(this.elevation),
      t[2] + distance * Math.cos(this.elevation) * Math.cos(this.azimuth),
    ];
    const viewProjection = multiply(perspective(fov, w / h, 0.05, 50), lookAt(eye, t, [0, 1, 0]));
    gl.useProgram(this.program);
    gl.uniformMatrix4fv(this.at.viewProjection, false, viewProjection);
    gl.uniform3fv(this.at.eye, eye);
    for (const name of ["floor", "body", "garment"]) {
      if (this.meshes[name]) this.meshes[name].draw(this.at.color);
    }
  }
}
