// The 3D view of diffnurbs.widgets.SurfaceView: draws the surfaces, curves and points the
// kernel evaluated, with three.js. One scene for the widget's life: an update replaces
// the numbers in the existing buffers (a new geometry only when a grid changes size), and
// the camera stays where the user left it.
//
// Source of src/diffnurbs/_static/surface_view.js, bundled with three.js by `make widgets`.
import {
  AmbientLight,
  Box3,
  BufferAttribute,
  BufferGeometry,
  Color,
  DirectionalLight,
  DoubleSide,
  Line,
  LineBasicMaterial,
  LineSegments,
  Mesh,
  MeshPhongMaterial,
  PerspectiveCamera,
  Points,
  PointsMaterial,
  Scene,
  Sphere,
  Vector3,
  WebGLRenderer,
} from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

function floats(value) {
  // Coordinates arrive as one binary buffer of little-endian float32 triples.
  const view = value instanceof DataView ? value : new DataView(value.buffer ?? value);
  return new Float32Array(view.buffer.slice(view.byteOffset, view.byteOffset + view.byteLength));
}

function gridTriangles(rows, columns) {
  const index = new Uint32Array(6 * (rows - 1) * (columns - 1));
  let k = 0;
  for (let i = 0; i + 1 < rows; i++) {
    for (let j = 0; j + 1 < columns; j++) {
      const a = i * columns + j;
      const b = a + columns;
      index.set([a, b, a + 1, a + 1, b, b + 1], k);
      k += 6;
    }
  }
  return index;
}

function gridLines(rows, columns) {
  // The rows and the columns of a control net, as segments between neighbours.
  const index = [];
  for (let i = 0; i < rows; i++) {
    for (let j = 0; j < columns; j++) {
      const a = i * columns + j;
      if (j + 1 < columns) index.push(a, a + 1);
      if (i + 1 < rows) index.push(a, a + columns);
    }
  }
  return new Uint32Array(index);
}

function shapeKey(item) {
  return `${item.kind}:${(item.shape ?? []).join("x")}:${item.count ?? ""}`;
}

function build(item) {
  const geometry = new BufferGeometry();
  const color = new Color(item.color);
  const [rows, columns] = item.shape ?? [0, 0];
  if (item.kind === "surface") {
    geometry.setIndex(new BufferAttribute(gridTriangles(rows, columns), 1));
    const material = new MeshPhongMaterial({
      color, side: DoubleSide, transparent: item.opacity < 1, opacity: item.opacity,
      shininess: 40,
    });
    return new Mesh(geometry, material);
  }
  if (item.kind === "net") {
    geometry.setIndex(new BufferAttribute(gridLines(rows, columns), 1));
    return new LineSegments(geometry, new LineBasicMaterial({ color }));
  }
  if (item.kind === "points") {
    return new Points(geometry, new PointsMaterial({ color, size: 7, sizeAttenuation: false }));
  }
  return new Line(geometry, new LineBasicMaterial({ color }));
}

function dispose(object) {
  object.geometry.dispose();
  object.material.dispose();
}

function render({ model, el }) {
  const root = document.createElement("div");
  root.className = "dn-view";
  const caption = document.createElement("div");
  caption.className = "dn-caption";
  const canvas = document.createElement("canvas");
  canvas.className = "dn-canvas";
  root.append(caption, canvas);
  el.appendChild(root);
  const width = model.get("width");
  const height = model.get("height");

  let renderer;
  try {
    renderer = new WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
  } catch (error) {
    caption.textContent = `This browser cannot draw 3D (WebGL): ${error.message}`;
    root.dataset.error = "webgl";
    return;
  }
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  renderer.setSize(width, height);
  renderer.setClearColor(0xffffff);
  const scene = new Scene();
  scene.add(new AmbientLight(0xffffff, 0.55));
  const camera = new PerspectiveCamera(35, width / height, 0.01, 1000);
  camera.up.set(0, 0, 1); // z up; the controls read it when they are made
  // The light sits at the camera, so the side the student looks at is always lit.
  const light = new DirectionalLight(0xffffff, 1.9);
  camera.add(light);
  scene.add(camera);
  const controls = new OrbitControls(camera, canvas);
  const objects = new Map(); // name -> three.js object
  let framed = false;
  let updates = 0; // drawn so far: the tests wait for this to settle

  function draw() {
    renderer.render(scene, camera);
    root.dataset.camera = JSON.stringify([...camera.position.toArray(),
      ...controls.target.toArray()]);
  }
  controls.addEventListener("change", draw);

  function frame() {
    // Fit the camera to what is drawn: once, for the first scene, and then on request only.
    const box = new Box3();
    for (const object of objects.values()) {
      object.geometry.computeBoundingBox();
      box.union(object.geometry.boundingBox);
    }
    if (box.isEmpty()) return false;
    const sphere = box.getBoundingSphere(new Sphere());
    const [x, y, z] = model.get("direction");
    const distance = (1.05 * sphere.radius) / Math.sin((Math.PI / 180) * camera.fov * 0.5);
    camera.position.copy(new Vector3(x, y, z).normalize().multiplyScalar(distance)
      .add(sphere.center));
    controls.target.copy(sphere.center);
    camera.near = distance / 100;
    camera.far = distance * 100;
    camera.updateProjectionMatrix();
    controls.update();
    return true;
  }

  function update() {
    const items = model.get("items");
    for (const [name, object] of objects) {
      if (!(name in items) || object.userData.key !== shapeKey(items[name])) {
        scene.remove(object);
        dispose(object);
        objects.delete(name);
      }
    }
    for (const [name, item] of Object.entries(items)) {
      let object = objects.get(name);
      if (!object) {
        object = build(item);
        object.userData.key = shapeKey(item);
        objects.set(name, object);
        scene.add(object);
      }
      const values = floats(item.positions);
      const position = object.geometry.getAttribute("position");
      if (position && position.array.length === values.length) {
        position.array.set(values); // the same buffer, new numbers
        position.needsUpdate = true;
      } else {
        object.geometry.setAttribute("position", new BufferAttribute(values, 3));
      }
      if (item.kind === "surface") object.geometry.computeVertexNormals();
      object.geometry.computeBoundingSphere();
      object.material.color.set(item.color);
    }
    caption.textContent = model.get("caption");
    const reframe = String(model.get("reframe"));
    if (!framed || reframe !== root.dataset.reframe) {
      framed = frame();
      root.dataset.reframe = reframe;
    }
    draw();
    root.dataset.updates = String(updates++);
    root.dataset.geometries = String(renderer.info.memory.geometries);
  }

  model.on("change:items", update);
  model.on("change:caption", () => { caption.textContent = model.get("caption"); });
  update();
  return () => {
    for (const object of objects.values()) dispose(object);
    controls.dispose();
    renderer.dispose();
  };
}

export default { render };
