// Stick-figure robot from the server's kinematics (/api/robot points), in two orthographic views:
// side (X-Z) and top (X-Y). The scale comes from the robot's view box, not from the pose, so the
// picture does not jump as the arm moves. Works for any backend: it only draws named points.

const COLORS = { grid: "#222b36", axis: "#56657a", link: "#e8edf3", joint: "#4fb3ff", flange: "#ffcc4d",
  tool: "#ff8a3d", text: "#9fb0c3", box: "#3d4a5c", tcp: "#ff3df5", triad: ["#ff5c5c", "#5cff7a", "#5ca8ff"] };
const GRID_MM = 100;
const TOOL_MM = 60; // length of the drawn tool direction
const TRIAD_MM = 40; // length of the TCP's drawn x, y, z axes

export class ArmView {
  constructor(sideCanvas, topCanvas) {
    this.views = [
      { canvas: sideCanvas, a: 0, b: 2, title: "side  X–Z", h: "X", v: "Z" },
      { canvas: topCanvas, a: 0, b: 1, title: "top  X–Y", h: "X", v: "Y" },
    ];
    this.robot = null;
    const ro = new ResizeObserver(() => this.draw(this.robot));
    for (const v of this.views) ro.observe(v.canvas);
  }

  draw(robot) {
    this.robot = robot;
    for (const view of this.views) this.drawView(view, robot);
  }

  drawView(view, robot) {
    const { canvas } = view;
    const dpr = window.devicePixelRatio || 1;
    const w = canvas.clientWidth;
    const h = canvas.clientHeight;
    if (w === 0 || h === 0) return;
    if (canvas.width !== Math.round(w * dpr)) canvas.width = Math.round(w * dpr);
    if (canvas.height !== Math.round(h * dpr)) canvas.height = Math.round(h * dpr);
    const g = canvas.getContext("2d");
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.clearRect(0, 0, w, h);
    g.font = "12px system-ui, sans-serif";
    if (!robot || !robot.points || !robot.view_box_mm) {
      g.fillStyle = COLORS.text;
      g.fillText(`${view.title}: no geometry`, 8, 16);
      return;
    }
    const box = robot.view_box_mm;
    const pad = 0.08 * Math.max(box.max[view.a] - box.min[view.a], box.max[view.b] - box.min[view.b]);
    const h0 = box.min[view.a] - pad;
    const h1 = box.max[view.a] + pad;
    const v0 = box.min[view.b] - pad;
    const v1 = box.max[view.b] + pad;
    const scale = Math.min((w - 8) / (h1 - h0), (h - 8) / (v1 - v0));
    const ox = (w - (h1 - h0) * scale) / 2;
    const oy = h - (h - (v1 - v0) * scale) / 2;
    const sx = (x) => ox + (x - h0) * scale;
    const sy = (y) => oy - (y - v0) * scale;
    const px = (p) => [sx(p[view.a]), sy(p[view.b])];

    this.grid(g, view, { h0, h1, v0, v1, sx, sy });
    // The work envelope (Cartesian robots: the strokes; arms: the reach box), dashed.
    g.save();
    g.strokeStyle = COLORS.box;
    g.setLineDash([4, 4]);
    g.strokeRect(sx(box.min[view.a]), sy(box.max[view.b]), (box.max[view.a] - box.min[view.a]) * scale,
      (box.max[view.b] - box.min[view.b]) * scale);
    g.restore();

    const pts = robot.points.map((p) => px(p.xyz_mm));
    g.strokeStyle = COLORS.link;
    g.lineWidth = 5;
    g.lineCap = "round";
    g.lineJoin = "round";
    g.beginPath();
    pts.forEach(([x, y], i) => (i === 0 ? g.moveTo(x, y) : g.lineTo(x, y)));
    g.stroke();
    g.fillStyle = COLORS.joint;
    for (const [x, y] of pts.slice(0, -1)) {
      g.beginPath();
      g.arc(x, y, 4, 0, 2 * Math.PI);
      g.fill();
    }
    const end = robot.points[robot.points.length - 1];
    const [fx, fy] = px(end.xyz_mm);
    if (end.approach) { // which way the tool points
      const tip = px(end.xyz_mm.map((v, i) => v + TOOL_MM * end.approach[i]));
      g.strokeStyle = COLORS.tool;
      g.lineWidth = 2;
      g.beginPath();
      g.moveTo(fx, fy);
      g.lineTo(tip[0], tip[1]);
      g.stroke();
    }
    g.fillStyle = COLORS.flange;
    g.beginPath();
    g.arc(fx, fy, 5, 0, 2 * Math.PI);
    g.fill();
    this.drawTcp(g, robot.tcp, [fx, fy], px, view);
    g.fillStyle = COLORS.text;
    g.fillText(view.title, 8, 16);
  }

  /** The active tool's TCP: a line from the flange, its x y z triad and a dot (in its own colour). The
   * canvas's data-tcp says where it was drawn (CSS px) and for which tool, for tests and tools. */
  drawTcp(g, tcp, flangeAt, px, view) {
    if (!tcp) {
      delete view.canvas.dataset.tcp;
      return;
    }
    const [tx, ty] = px(tcp.xyz_mm);
    g.lineWidth = 2;
    g.strokeStyle = COLORS.tcp;
    g.setLineDash([5, 3]);
    g.beginPath();
    g.moveTo(flangeAt[0], flangeAt[1]);
    g.lineTo(tx, ty);
    g.stroke();
    g.setLineDash([]);
    tcp.axes.forEach((axis, i) => {
      const [ex, ey] = px(tcp.xyz_mm.map((v, k) => v + TRIAD_MM * axis[k]));
      g.strokeStyle = COLORS.triad[i];
      g.beginPath();
      g.moveTo(tx, ty);
      g.lineTo(ex, ey);
      g.stroke();
    });
    g.fillStyle = COLORS.tcp;
    g.beginPath();
    g.arc(tx, ty, 4, 0, 2 * Math.PI);
    g.fill();
    view.canvas.dataset.tcp = JSON.stringify({ tool: tcp.tool, x: tx, y: ty });
  }

  grid(g, view, { h0, h1, v0, v1, sx, sy }) {
    g.strokeStyle = COLORS.grid;
    g.lineWidth = 1;
    g.beginPath();
    for (let x = Math.ceil(h0 / GRID_MM) * GRID_MM; x <= h1; x += GRID_MM) { g.moveTo(sx(x), sy(v0)); g.lineTo(sx(x), sy(v1)); }
    for (let y = Math.ceil(v0 / GRID_MM) * GRID_MM; y <= v1; y += GRID_MM) { g.moveTo(sx(h0), sy(y)); g.lineTo(sx(h1), sy(y)); }
    g.stroke();
    // World axes through the origin, when it is in view.
    g.strokeStyle = COLORS.axis;
    g.beginPath();
    if (v0 <= 0 && v1 >= 0) { g.moveTo(sx(h0), sy(0)); g.lineTo(sx(h1), sy(0)); }
    if (h0 <= 0 && h1 >= 0) { g.moveTo(sx(0), sy(v0)); g.lineTo(sx(0), sy(v1)); }
    g.stroke();
    g.fillStyle = COLORS.text;
    g.fillText(`+${view.h} →`, sx(h1) - 34, sy(v0) - 6);
    g.fillText(`↑ +${view.v}`, sx(h0) + 4, sy(v1) + 30);
    g.fillText(`grid ${GRID_MM} mm`, sx(h1) - 76, sy(v1) + 14);
  }
}
