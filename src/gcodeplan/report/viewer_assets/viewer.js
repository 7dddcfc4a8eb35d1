/* gcodeplan viewer: timeline (uPlot), toolpath per layer, inspector, layer bars.
 *
 * The data (see gcodeplan/report/viewer.py) are per-move columns. Every move's speed profile is rebuilt
 * here in float64 from its PLAN fields: a trapezoid (accel, cruise, decel), the time-optimal jerk-limited
 * S-curve ramps of docs/design.md, or, for blend plans, the stored SEGMENT pieces (velocity and
 * acceleration vectors). The timeline draws, per pixel column, the exact min/max of the plan over that
 * column (a min/max tree over the moves for the columns' inner moves, the clipped profile for the two
 * moves at its edges), and once the window holds few moves, the plan's exact pieces themselves.
 */
(function () {
  'use strict';
  const META = JSON.parse(document.getElementById('gpv-meta').textContent);
  const $ = (id) => document.getElementById(id);
  const root = $('gpv');
  const CTORS = { f64: Float64Array, f32: Float32Array, u32: Uint32Array, i32: Int32Array, i16: Int16Array, u8: Uint8Array };
  const EXACT_MAX_MOVES = 1500;   // at most this many moves in the window: draw the exact pieces
  const SUBDIV = 8;               // samples inside a curved piece (S-curve jerk phases, blends)
  const n = META.n;
  const KDWELL = META.kind_dwell, KWAIT = META.kind_wait, KTRAVEL = 0, KPRINT = 1, KEXTRUDE = 2;
  // a program that never extrudes (a CNC program): its feed moves are the cuts, its rapids (G0) the travel
  const CNC = !!META.cnc, FRAPID = 1;
  const isCut = (i) => KIND[i] === KPRINT || (CNC && KIND[i] === KTRAVEL && !(FLAGS[i] & FRAPID));

  // ------------------------------------------------------------------------------------ decoding
  function b64bytes(s) {
    s = s.trim();
    if (Uint8Array.fromBase64) return Uint8Array.fromBase64(s);
    const bin = atob(s);
    const u = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) u[i] = bin.charCodeAt(i);
    return u;
  }
  async function inflate(bytes) {
    const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate'));
    return new Uint8Array(await new Response(stream).arrayBuffer());
  }
  async function decodeArray(name) {
    const el = $('gpv-a-' + name);
    if (!el) return null;
    const C = CTORS[el.dataset.dtype];
    const count = +el.dataset.n;
    const bytes = await inflate(b64bytes(el.textContent));
    const size = C.BYTES_PER_ELEMENT;
    if (bytes.length !== count * size) throw new Error('gcodeplan viewer: array ' + name + ' is damaged');
    let buf = bytes;
    if (size > 1 && el.dataset.shuffle === '1') {   // undo the byte shuffle: plane p holds byte p of every element
      buf = new Uint8Array(count * size);
      for (let p = 0; p < size; p++) {
        const off = p * count;
        for (let i = 0, j = p; i < count; i++, j += size) buf[j] = bytes[off + i];
      }
    }
    el.textContent = '';   // the base64 text is no longer needed
    return new C(buf.buffer, 0, count);
  }

  let T, VS, VC, VE, ACC, DEC, F, X, Y, LINE, KIND, FLAGS, FEAT, LAYER, LIMIT, OBJ, TEXTLINES;
  let SEGOFF = null, SEG = null;
  const J = META.jerk > 0 ? META.jerk : 0;
  const BLEND = !!META.segments || META.mode === 'blend';   // rows drawn from their SEGMENT pieces
  let TEND = META.t_end;

  async function load() {
    const names = ['t_lo', 't_hi', 'vs', 'vc', 've_res', 'acc', 'dec', 'feed', 'x', 'y', 'line_d', 'kind', 'flags',
      'feature', 'layer_d', 'limit', 'object', 'text_lines_d'];
    const segNames = ['seg_count', 'seg_t0_lo', 'seg_t0_hi', 'seg_dt', 'seg_vx', 'seg_vy', 'seg_vz', 'seg_ve',
      'seg_ax', 'seg_ay', 'seg_az', 'seg_ae'];
    const all = names.concat(BLEND ? segNames : []);
    const got = await Promise.all(all.map(decodeArray));
    const A = {};
    all.forEach((k, i) => { A[k] = got[i]; });
    const scale = Math.pow(2, -META.t_bits);
    T = new Float64Array(n + 1);
    let cum = 0;
    for (let i = 0; i <= n; i++) { cum += A.t_hi[i] * 4294967296 + A.t_lo[i]; T[i] = cum * scale; }
    TEND = T[n];
    VS = A.vs; VC = A.vc;
    VE = A.ve_res;   // stored as end speed − next start speed (exact: both are multiples of 2^-v_bits)
    for (let i = 0; i < n; i++) VE[i] += i + 1 < n ? VS[i + 1] : 0; ACC = A.acc; DEC = A.dec; F = A.feed; X = A.x; Y = A.y;
    KIND = A.kind; FLAGS = A.flags; FEAT = A.feature; LIMIT = A.limit; OBJ = A.object;
    LINE = new Float64Array(n); LAYER = new Int32Array(n);
    let l = 0, ly = 0;
    for (let i = 0; i < n; i++) { l += A.line_d[i]; LINE[i] = l; ly += A.layer_d[i]; LAYER[i] = ly; }
    const td = A.text_lines_d;
    TEXTLINES = new Float64Array(td.length);
    l = 0;
    for (let i = 0; i < td.length; i++) { l += td[i]; TEXTLINES[i] = l; }
    if (BLEND) {
      const cnt = A.seg_count, m = A.seg_dt.length;
      SEGOFF = new Uint32Array(n + 1);
      for (let i = 0; i < n; i++) SEGOFF[i + 1] = SEGOFF[i] + cnt[i];
      const t0 = new Float64Array(m);
      for (let k = 0; k < m; k++) t0[k] = (A.seg_t0_hi[k] * 4294967296 + A.seg_t0_lo[k]) * scale;
      SEG = { t0: t0, dt: A.seg_dt, vx: A.seg_vx, vy: A.seg_vy, vz: A.seg_vz, ve: A.seg_ve,
              ax: A.seg_ax, ay: A.seg_ay, az: A.seg_az, ae: A.seg_ae };
    }
  }

  // ------------------------------------------------------------------------------------ profiles
  // A piece: {t0, dt, v0, a0, j} (speed v0 + a0·τ + j·τ²/2 along the path) or, for blends,
  // {t0, dt, vec: [vx, vy, vz, ax, ay, az]} (speed |v + a·τ|).
  function ramp(dv, a, j) {
    // time-optimal jerk-limited speed change by dv from and to zero acceleration: (t1, t2, peak accel)
    const t1 = Math.min(a / j, Math.sqrt(dv / j));
    const ap = j * t1;
    return [t1, Math.max(0, dv / ap - t1), ap];
  }
  function pieces(i) {
    const t0 = T[i], dur = T[i + 1] - T[i];
    if (!(dur > 0)) return [];
    const k = KIND[i];
    if (k === KDWELL || k === KWAIT) return [{ t0: t0, dt: dur, v0: 0, a0: 0, j: 0 }];
    if (BLEND) {
      const out = [];
      const e = k === KEXTRUDE;
      for (let s = SEGOFF[i]; s < SEGOFF[i + 1]; s++) {
        const vec = e ? [SEG.ve[s], 0, 0, SEG.ae[s], 0, 0]
                      : [SEG.vx[s], SEG.vy[s], SEG.vz[s], SEG.ax[s], SEG.ay[s], SEG.az[s]];
        out.push({ t0: SEG.t0[s], dt: SEG.dt[s], vec: vec });
      }
      return out.length ? out : [{ t0: t0, dt: dur, v0: 0, a0: 0, j: 0 }];
    }
    const vs = VS[i], vc = VC[i], ve = VE[i], a = ACC[i], d = DEC[i];
    const out = [];
    if (J > 0) {
      let t = t0, accT = 0, decT = 0, ru = null, rd = null;
      if (vc > vs && a > 0) { ru = ramp(vc - vs, a, J); accT = 2 * ru[0] + ru[1]; }
      if (vc > ve && d > 0) { rd = ramp(vc - ve, d, J); decT = 2 * rd[0] + rd[1]; }
      const ct = Math.max(0, dur - accT - decT);
      if (ru) {
        const [t1, t2, ap] = ru;
        out.push({ t0: t, dt: t1, v0: vs, a0: 0, j: J });
        if (t2 > 0) out.push({ t0: t + t1, dt: t2, v0: vs + 0.5 * ap * t1, a0: ap, j: 0 });
        out.push({ t0: t + t1 + t2, dt: t1, v0: vc - 0.5 * ap * t1, a0: ap, j: -J });
        t += accT;
      }
      if (ct > 0) { out.push({ t0: t, dt: ct, v0: vc, a0: 0, j: 0 }); t += ct; }
      if (rd) {
        const [t1, t2, ap] = rd;
        out.push({ t0: t, dt: t1, v0: vc, a0: 0, j: -J });
        if (t2 > 0) out.push({ t0: t + t1, dt: t2, v0: vc - 0.5 * ap * t1, a0: -ap, j: 0 });
        out.push({ t0: t + t1 + t2, dt: t1, v0: ve + 0.5 * ap * t1, a0: -ap, j: J });
      }
    } else {
      const at = vc > vs && a > 0 ? (vc - vs) / a : 0;
      const dt = vc > ve && d > 0 ? (vc - ve) / d : 0;
      const ct = Math.max(0, dur - at - dt);
      if (at > 0) out.push({ t0: t0, dt: at, v0: vs, a0: a, j: 0 });
      if (ct > 0) out.push({ t0: t0 + at, dt: ct, v0: vc, a0: 0, j: 0 });
      if (dt > 0) out.push({ t0: t0 + at + ct, dt: dt, v0: vc, a0: -d, j: 0 });
    }
    return out.length ? out : [{ t0: t0, dt: dur, v0: vc, a0: 0, j: 0 }];
  }
  function evalPiece(p, tau) {   // [speed mm/s, path acceleration mm/s²]
    if (tau < 0) tau = 0; else if (tau > p.dt) tau = p.dt;
    if (!p.vec) return [p.v0 + tau * (p.a0 + 0.5 * tau * p.j), p.a0 + p.j * tau];
    const q = p.vec;
    const vx = q[0] + q[3] * tau, vy = q[1] + q[4] * tau, vz = q[2] + q[5] * tau;
    const s = Math.sqrt(vx * vx + vy * vy + vz * vz);
    const am = Math.sqrt(q[3] * q[3] + q[4] * q[4] + q[5] * q[5]);
    let at;
    if (s > 0) at = (vx * q[3] + vy * q[4] + vz * q[5]) / s;
    else at = tau * 2 < p.dt ? am : -am;     // at rest: leaving (start) or arriving (end) along a
    return [s, at];
  }
  function pieceAt(ps, t) {
    for (let k = 0; k < ps.length; k++) if (t < ps[k].t0 + ps[k].dt || k === ps.length - 1) return ps[k];
    return null;
  }
  function phaseName(i, p) {
    const k = KIND[i];
    if (k === KDWELL) return 'dwell';
    if (k === KWAIT) return 'wait';
    if (!p) return '';
    if (p.vec) return Math.hypot(p.vec[3], p.vec[4], p.vec[5]) === 0 ? 'cruise' : 'blend / straight';
    if (p.j !== 0) return p.j > 0 === (p.a0 >= 0 && p.t0 < T[i] + 0.5 * (T[i + 1] - T[i])) ? 'accel' : 'decel';
    return p.a0 > 0 ? 'accel' : (p.a0 < 0 ? 'decel' : 'cruise');
  }
  // min/max of speed and acceleration of move i over [ta, tb] (the whole move by default)
  function clipRange(i, ta, tb, r) {
    const ps = pieces(i);
    for (const p of ps) {
      const a = Math.max(ta, p.t0), b = Math.min(tb, p.t0 + p.dt);
      if (b < a) continue;
      const taus = [a - p.t0, b - p.t0];
      if (p.vec) {   // |v + aτ| is smallest where (v + aτ)·a = 0
        const q = p.vec, aa = q[3] * q[3] + q[4] * q[4] + q[5] * q[5];
        if (aa > 0) {
          const ts = -(q[0] * q[3] + q[1] * q[4] + q[2] * q[5]) / aa;
          if (ts > taus[0] && ts < taus[1]) taus.push(ts);
        }
      }
      for (const tau of taus) {
        const [v, acc] = evalPiece(p, tau);
        if (v < r[0]) r[0] = v; if (v > r[1]) r[1] = v;
        if (acc < r[2]) r[2] = acc; if (acc > r[3]) r[3] = acc;
      }
    }
    const f = feedOf(i);
    if (f === f) { if (f < r[4]) r[4] = f; if (f > r[5]) r[5] = f; }
  }
  function feedOf(i) {
    const k = KIND[i], f = F[i];
    return (k === KDWELL || k === KWAIT || !(f > 0) || !isFinite(f) || !(T[i + 1] > T[i])) ? NaN : f;
  }
  function moveAt(t) {   // the last move starting at or before t (moves of zero duration are skipped over)
    let lo = 0, hi = n - 1;
    if (!(t > T[0])) return 0;
    while (lo < hi) { const mid = (lo + hi + 1) >> 1; if (T[mid] <= t) lo = mid; else hi = mid - 1; }
    return lo;
  }

  // ------------------------------------------------------------------------------------ min/max tree
  // The pyramid: level 0 the moves, each level above the min/max of two below (a segment tree), so a
  // column of any width gets the exact min/max of the moves inside it in O(log n).
  let NT = 1, TR = null;   // TR[c]: Float32Array(2·NT) for channels vmin, vmax, amin, amax, fmin, fmax
  function buildTree() {
    while (NT < n) NT <<= 1;
    TR = [];
    for (let c = 0; c < 6; c++) TR.push(new Float32Array(2 * NT).fill(c % 2 ? -Infinity : Infinity));
    const [vmin, vmax, amin, amax, fmin, fmax] = TR;
    const r = [0, 0, 0, 0, 0, 0];
    for (let i = 0; i < n; i++) {
      const L = NT + i;
      if (!(T[i + 1] > T[i])) continue;
      const k = KIND[i];
      if (k === KDWELL || k === KWAIT) { vmin[L] = vmax[L] = amin[L] = amax[L] = 0; continue; }
      if (BLEND) {
        r[0] = r[2] = r[4] = Infinity; r[1] = r[3] = r[5] = -Infinity;
        clipRange(i, -Infinity, Infinity, r);
        vmin[L] = r[0]; vmax[L] = r[1]; amin[L] = r[2]; amax[L] = r[3];
      } else {
        const vs = VS[i], vc = VC[i], ve = VE[i], dur = T[i + 1] - T[i];
        vmax[L] = Math.max(vs, vc, ve); vmin[L] = Math.min(vs, ve, vc);
        let up = 0, down = 0, cruise = false;
        if (J > 0) {
          if (vc > vs && ACC[i] > 0) up = ramp(vc - vs, ACC[i], J)[2];
          if (vc > ve && DEC[i] > 0) down = ramp(vc - ve, DEC[i], J)[2];
          cruise = true;   // S-curve ramps start and end at zero acceleration
        } else {
          const at = vc > vs && ACC[i] > 0 ? (vc - vs) / ACC[i] : 0;
          const dt = vc > ve && DEC[i] > 0 ? (vc - ve) / DEC[i] : 0;
          if (at > 0) up = ACC[i];
          if (dt > 0) down = DEC[i];
          cruise = dur - at - dt > 0 || (at === 0 && dt === 0);
        }
        amax[L] = up > 0 ? up : (cruise ? 0 : -down);
        amin[L] = down > 0 ? -down : (cruise ? 0 : up);
      }
      const f = feedOf(i);
      if (f === f) { fmin[L] = f; fmax[L] = f; }
    }
    for (let c = 0; c < 6; c += 2) {
      const lo = TR[c], hi = TR[c + 1];
      for (let k = NT - 1; k >= 1; k--) {
        const a = lo[2 * k], b = lo[2 * k + 1], x = hi[2 * k], y = hi[2 * k + 1];
        lo[k] = a < b ? a : b;
        hi[k] = x > y ? x : y;
      }
    }
  }
  function query(l, r, out) {   // moves l..r inclusive, into out[0..5]
    l += NT; r += NT + 1;
    while (l < r) {
      if (l & 1) { acc(l, out); l++; }
      if (r & 1) { r--; acc(r, out); }
      l >>= 1; r >>= 1;
    }
  }
  function acc(k, out) {
    for (let c = 0; c < 6; c += 2) {
      const lo = TR[c][k], hi = TR[c + 1][k];
      if (lo < out[c]) out[c] = lo;
      if (hi > out[c + 1]) out[c + 1] = hi;
    }
  }

  // ------------------------------------------------------------------------------------ timeline data
  const view = { t0: 0, t1: 1, layer: null, mode: 'envelope', points: 0, drawn: null, hl: null, pathSegments: 0, highlighted: 0,
                 pinned: null, hover: null };
  function seriesFor(t0, t1, cols) {
    const ia = moveAt(Math.max(t0, 0)), ib = moveAt(Math.min(t1, TEND));
    const xs = [], s = [[], [], [], [], [], []], mv = [];
    if (ib - ia + 1 <= EXACT_MAX_MOVES) {
      view.mode = 'exact';
      for (let i = Math.max(0, ia - 1); i <= Math.min(n - 1, ib + 1); i++) {
        const f = feedOf(i);
        const fv = f === f ? f : null;
        for (const p of pieces(i)) {
          const curved = p.vec || p.j !== 0;
          const steps = curved ? SUBDIV : 1;
          for (let q = 0; q <= steps; q++) {
            const tau = p.dt * q / steps;
            const [v, a] = evalPiece(p, tau);
            xs.push(p.t0 + tau);
            s[0].push(v); s[1].push(v); s[2].push(fv); s[3].push(fv); s[4].push(a); s[5].push(a);
            mv.push(i);
          }
          if (p.vec) {   // the speed minimum inside a blend is a vertex too
            const q = p.vec, aa = q[3] * q[3] + q[4] * q[4] + q[5] * q[5];
            const ts = aa > 0 ? -(q[0] * q[3] + q[1] * q[4] + q[2] * q[5]) / aa : -1;
            if (ts > 0 && ts < p.dt) {
              // insert in time order
              let at = xs.length - 1;
              while (at > 0 && xs[at - 1] > p.t0 + ts) at--;
              const [v, a] = evalPiece(p, ts);
              xs.splice(at, 0, p.t0 + ts);
              for (let c = 0; c < 6; c++) s[c].splice(at, 0, c < 2 ? v : (c < 4 ? fv : a));
              mv.splice(at, 0, i);
            }
          }
        }
      }
      // the drawn curve's extremes inside the window (vertices of the moves it shows)
      // (times here are on the page's 2^-t_bits grid: a window given in the plan's own float64 times
      // may differ from them by that much, hence the tolerance)
      const d = { vmin: Infinity, vmax: -Infinity, amin: Infinity, amax: -Infinity };
      const eps = 1e-9 * Math.max(1, Math.abs(t1));
      for (let k = 0; k < xs.length; k++) {
        const i = mv[k];
        if (xs[k] < t0 - eps || xs[k] > t1 + eps || T[i + 1] <= t0 + eps || T[i] >= t1 - eps) continue;
        d.vmin = Math.min(d.vmin, s[1][k]); d.vmax = Math.max(d.vmax, s[0][k]);
        d.amin = Math.min(d.amin, s[5][k]); d.amax = Math.max(d.amax, s[4][k]);
      }
      view.drawn = d;
    } else {
      view.mode = 'envelope';
      const dt = (t1 - t0) / cols;
      const r = [0, 0, 0, 0, 0, 0], m = [0, 0, 0, 0, 0, 0];
      const d = { vmin: Infinity, vmax: -Infinity, amin: Infinity, amax: -Infinity };
      for (let c = 0; c < cols; c++) {
        const ta = t0 + c * dt, tb = ta + dt;
        xs.push(ta + 0.5 * dt);
        if (tb <= 0 || ta >= TEND) { for (let q = 0; q < 6; q++) s[q].push(null); continue; }
        const a = moveAt(Math.max(ta, 0));
        let b = moveAt(Math.min(tb, TEND));
        if (b > a && T[b] >= tb) b--;
        r[0] = r[2] = r[4] = Infinity; r[1] = r[3] = r[5] = -Infinity;
        m[0] = m[2] = m[4] = Infinity; m[1] = m[3] = m[5] = -Infinity;
        clipRange(a, ta, tb, m);
        if (b > a) clipRange(b, ta, tb, m);
        if (b - a > 1) query(a + 1, b - 1, r);
        // r: tree order (vmin, vmax, amin, amax, fmin, fmax); m: clip order (vmin, vmax, amin, amax, fmin, fmax)
        const vmin = Math.min(r[0], m[0]), vmax = Math.max(r[1], m[1]);
        const amin = Math.min(r[2], m[2]), amax = Math.max(r[3], m[3]);
        const fmin = Math.min(r[4], m[4]), fmax = Math.max(r[5], m[5]);
        const ok = vmax >= vmin;
        s[0].push(ok ? vmax : null); s[1].push(ok ? vmin : null);
        s[2].push(fmax >= fmin ? fmax : null); s[3].push(fmax >= fmin ? fmin : null);
        s[4].push(ok ? amax : null); s[5].push(ok ? amin : null);
        if (ok) {
          d.vmin = Math.min(d.vmin, vmin); d.vmax = Math.max(d.vmax, vmax);
          d.amin = Math.min(d.amin, amin); d.amax = Math.max(d.amax, amax);
        }
      }
      view.drawn = d;
    }
    view.points = xs.length;
    return [xs].concat(s);
  }

  // ------------------------------------------------------------------------------------ formatting
  function hms(t) {
    const s = Math.max(0, t), h = Math.floor(s / 3600), m = Math.floor((s - 3600 * h) / 60);
    const sec = s - 3600 * h - 60 * m;
    return h + ':' + String(m).padStart(2, '0') + ':' + (sec < 10 ? '0' : '') + sec.toFixed(3);
  }
  function tickDecimals(incr) {   // as many decimals as the tick spacing needs, no more
    return incr > 0 && isFinite(incr) ? Math.min(12, Math.max(0, Math.ceil(-Math.log10(incr) - 1e-9))) : 3;
  }
  function fmtAxisT(u, vals, axisIdx, space, incr) {
    const span = u.scales.x.max - u.scales.x.min;
    if (span > 600) return vals.map((v) => hms(v).replace(/\.\d+$/, ''));
    const d = tickDecimals(incr);
    return vals.map((v) => v.toFixed(d));
  }
  function axisSpaceT(u, axisIdx, lo, hi) {   // px between ticks: wide enough for the longest label
    const span = hi - lo;
    if (!(span > 0)) return 80;
    if (span > 600) return 80;
    const digits = Math.max(1, Math.ceil(Math.log10(Math.max(Math.abs(lo), Math.abs(hi), 1) + 1)));
    const chars = digits + 1 + tickDecimals(span / 8);
    return Math.max(60, 7.5 * chars + 24);
  }
  function esc(s) {
    return String(s).replace(/[&<>"]/g, (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;' })[c]);
  }

  // ------------------------------------------------------------------------------------ G-code text
  const blockCounts = META.text_blocks || [];
  const blockStart = [0];
  for (const c of blockCounts) blockStart.push(blockStart[blockStart.length - 1] + c);
  const blockCache = new Map();
  const utf8 = new TextDecoder('utf-8');
  function textOfLine(line) {
    let lo = 0, hi = TEXTLINES.length - 1, k = -1;
    while (lo <= hi) {
      const mid = (lo + hi) >> 1;
      if (TEXTLINES[mid] === line) { k = mid; break; }
      if (TEXTLINES[mid] < line) lo = mid + 1; else hi = mid - 1;
    }
    if (k < 0) return '';
    let b = 0;
    while (b + 1 < blockStart.length && blockStart[b + 1] <= k) b++;
    if (b >= blockCounts.length) return '';
    let blk = blockCache.get(b);
    if (!blk) {
      const el = $('gpv-text-' + b);
      const bytes = fzstd.decompress(b64bytes(el.textContent));
      const offs = [0];
      for (let q = 0; q < bytes.length; q++) if (bytes[q] === 10) offs.push(q + 1);
      blk = { bytes: bytes, offs: offs };
      if (blockCache.size > 8) blockCache.delete(blockCache.keys().next().value);
      blockCache.set(b, blk);
    }
    const q = k - blockStart[b];
    return utf8.decode(blk.bytes.subarray(blk.offs[q], Math.max(blk.offs[q], blk.offs[q + 1] - 1)));
  }

  // ------------------------------------------------------------------------------------ inspector
  function segAt(t) {   // the SEGMENT piece running at t (pieces are in time order: by move, then time)
    let lo = 0, hi = SEG.t0.length - 1;
    if (hi < 0) return -1;
    while (lo < hi) { const mid = (lo + hi + 1) >> 1; if (SEG.t0[mid] <= t) lo = mid; else hi = mid - 1; }
    return lo;
  }
  function inspectAt(t) {
    t = +t;
    const i = moveAt(Math.min(Math.max(t, 0), TEND));
    const ps = pieces(i);
    let p = ps.length ? pieceAt(ps, t) : null;
    if (BLEND && p && p.vec && !(t >= p.t0 && t <= p.t0 + p.dt)) {
      // a piece of a neighbouring row runs now (LinuxCNC: a blend arc's pieces belong to the row after it)
      const s = segAt(t);
      if (s >= 0 && t <= SEG.t0[s] + SEG.dt[s]) {
        const e = KIND[i] === KEXTRUDE;
        p = { t0: SEG.t0[s], dt: SEG.dt[s], vec: e ? [SEG.ve[s], 0, 0, SEG.ae[s], 0, 0]
          : [SEG.vx[s], SEG.vy[s], SEG.vz[s], SEG.ax[s], SEG.ay[s], SEG.az[s]] };
      }
    }
    const [v, a] = p ? evalPiece(p, t - p.t0) : [0, 0];
    const feat = FEAT[i];
    const ob = OBJ ? OBJ[i] : -1;
    const names = META.objects || [];
    const lay = LAYER[i];
    const z = lay >= 0 && lay < META.layer_z.length ? META.layer_z[lay] : null;
    const f = feedOf(i);
    return {
      time: t, move: i, speed: v, accel: a, feed: f === f ? f : null, phase: phaseName(i, p),
      line: LINE[i], text: textOfLine(LINE[i]),
      feature: feat >= 0 && feat < META.features.length ? META.features[feat] : null,
      layer: lay, z: z,
      object: OBJ && ob >= 0 ? (ob < names.length ? names[ob] : ob) : null,
      limit: META.limit_names[LIMIT[i]] || String(LIMIT[i]),
      kind: META.kind_names[KIND[i]] || String(KIND[i]),
      move_start: T[i], move_end: T[i + 1],
      start_v: VS[i], cruise_v: VC[i], end_v: VE[i]
    };
  }
  function showInspector(r) {
    const rows = [
      ['time', r.time.toFixed(6) + ' s (' + hms(r.time) + ')'],
      ['speed', r.speed.toFixed(6) + ' mm/s'],
      ['acceleration', r.accel.toFixed(3) + ' mm/s² (' + r.phase + ')'],
      ['requested feed', r.feed === null ? '–' : r.feed.toFixed(3) + ' mm/s'],
      ['move', '#' + r.move + ' (' + r.kind + '), ' + r.move_start.toFixed(6) + '–' + r.move_end.toFixed(6) + ' s; start '
        + r.start_v.toFixed(3) + ', peak ' + r.cruise_v.toFixed(3) + ', end ' + r.end_v.toFixed(3) + ' mm/s'],
      ['limited by', r.limit],
      ['G-code line', String(r.line)],
      ['text', r.text],
      ['feature', r.feature === null ? '–' : r.feature],
      [BY_Z ? 'Z level' : 'layer', groupName(r.layer)],
      ['object', r.object === null ? '–' : String(r.object)]
    ];
    $('gpv-insp').innerHTML = rows.map(([k, v]) => '<tr><th>' + esc(k) + '</th><td' + (k === 'text' ? ' class="gpv-code"' : '')
      + '>' + esc(v) + '</td></tr>').join('');
  }

  // ------------------------------------------------------------------------------------ toolpath
  // a CNC program (no layers) is grouped by Z level: its moves at one cutting height (viewer.py)
  const BY_Z = META.group_by === 'z';   // (set before the toolpath is indexed)
  function groupName(ly, short) {
    if (BY_Z) {
      if (ly < 0) return 'before the first cut';
      const z = (META.group_z || [])[ly];
      return (short ? 'Z level ' : '') + ly + (z === undefined ? '' : ' (z ' + z.toFixed(3) + ' mm)');
    }
    if (ly < 0) return 'before the first layer';
    const z = ly < META.layer_z.length ? META.layer_z[ly] : null;
    return (short ? 'layer ' : '') + ly + (short || z === null ? '' : ' (z ' + z.toFixed(3) + ' mm)');
  }
  const layers = [];          // sorted layer values
  const layerRuns = new Map(); // layer -> [[i0, i1), ...]
  let bbox = null, vColorMax = 1;
  function indexLayers() {
    let cur = null, start = 0;
    for (let i = 0; i <= n; i++) {
      const ly = i < n ? LAYER[i] : null;
      if (ly !== cur) {
        if (cur !== null) {
          if (!layerRuns.has(cur)) layerRuns.set(cur, []);
          layerRuns.get(cur).push([start, i]);
        }
        cur = ly; start = i;
      }
    }
    for (const k of layerRuns.keys()) layers.push(k);
    layers.sort((a, b) => a - b);
    // the frame: what is printed in the layers (not the purge line of the start G-code, 'Custom' in
    // PrusaSlicer, before the first layer in Cura; nor travel to a park position), else all that moves
    const custom = META.features.map((f) => /custom/i.test(f));
    const box = (all) => {
      let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
      let px = META.first_pos[0], py = META.first_pos[1];
      for (let i = 0; i < n; i++) {
        const k = KIND[i];
        const inFrame = all ? (k === KPRINT || k === KTRAVEL)
                            : (isCut(i) && (LAYER[i] >= 0 || BY_Z || CNC) && !(FEAT[i] >= 0 && custom[FEAT[i]]));
        if (inFrame && (X[i] !== px || Y[i] !== py)) {
          x0 = Math.min(x0, px, X[i]); x1 = Math.max(x1, px, X[i]); y0 = Math.min(y0, py, Y[i]); y1 = Math.max(y1, py, Y[i]);
          if (isCut(i) && VC[i] > vColorMax) vColorMax = VC[i];
        }
        px = X[i]; py = Y[i];
      }
      return [x0, x1, y0, y1];
    };
    let [x0, x1, y0, y1] = box(false);
    if (!(x1 >= x0)) [x0, x1, y0, y1] = box(true);
    if (!(x1 >= x0)) [x0, x1, y0, y1] = [0, 1, 0, 1];
    const m = 0.04 * Math.max(x1 - x0, y1 - y0, 1);
    bbox = [x0 - m, x1 + m, y0 - m, y1 + m];
  }
  const VIRIDIS = [[68, 1, 84], [72, 40, 120], [62, 74, 137], [49, 104, 142], [38, 130, 142], [31, 158, 137],
                   [53, 183, 121], [110, 206, 88], [181, 222, 43], [253, 231, 37]];
  const NBUCKET = 32;
  function bucketColor(b) {
    const x = b / (NBUCKET - 1) * (VIRIDIS.length - 1), k = Math.min(Math.floor(x), VIRIDIS.length - 2), f = x - k;
    const c = VIRIDIS[k].map((v, q) => Math.round(v + f * (VIRIDIS[k + 1][q] - v)));
    return 'rgb(' + c.join(',') + ')';
  }
  const canvas = $('gpv-path');
  let pathXf = null;
  function sizeCanvas(c, w, h) {
    const dpr = window.devicePixelRatio || 1;
    c.style.width = w + 'px'; c.style.height = h + 'px';
    c.width = Math.round(w * dpr); c.height = Math.round(h * dpr);
    const g = c.getContext('2d');
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    return g;
  }
  function startOf(i) { return i > 0 ? [X[i - 1], Y[i - 1]] : [META.first_pos[0], META.first_pos[1]]; }
  function drawPath() {
    const w = parseFloat(canvas.style.width), h = parseFloat(canvas.style.height);
    const g = canvas.getContext('2d');
    g.clearRect(0, 0, w, h);
    const [x0, x1, y0, y1] = bbox, pad = 12;
    const sc = Math.min((w - 2 * pad) / (x1 - x0), (h - 2 * pad) / (y1 - y0));
    const ox = pad + 0.5 * ((w - 2 * pad) - sc * (x1 - x0)), oy = pad + 0.5 * ((h - 2 * pad) - sc * (y1 - y0));
    pathXf = { sc: sc, ox: ox, oy: oy, x0: x0, y1: y1 };
    const px = (x) => ox + (x - x0) * sc, py = (y) => oy + (y1 - y) * sc;
    g.strokeStyle = '#eee'; g.lineWidth = 1; g.strokeRect(px(x0), py(y1), (x1 - x0) * sc, (y1 - y0) * sc);
    const runs = layerRuns.get(view.layer) || [];
    const buckets = Array.from({ length: NBUCKET }, () => []);
    const travel = [], hl = [], prints = [];
    let count = 0, vLo = Infinity, vHi = -Infinity;
    for (const [a, b] of runs) {
      for (let i = a; i < b; i++) {
        const k = KIND[i];
        if (k !== KPRINT && k !== KTRAVEL) continue;
        const [sx, sy] = startOf(i);
        if (sx === X[i] && sy === Y[i]) continue;
        count++;
        if (!isCut(i)) travel.push(i);
        else { prints.push(i); if (VC[i] < vLo) vLo = VC[i]; if (VC[i] > vHi) vHi = VC[i]; }
        if (view.hl && T[i + 1] > view.hl[0] && T[i] < view.hl[1]) hl.push(i);
      }
    }
    // the colour scale spans the speeds of the moves drawn (this layer's), not the whole print's
    if (!(vHi >= vLo)) { vLo = 0; vHi = 1; }
    if (vHi - vLo < 0.05 * vHi) vLo = 0;    // one speed (or nearly): a scale from rest, not a flat colour
    const range = vHi - vLo;
    for (const i of prints) {
      const b = range > 0 ? Math.floor((VC[i] - vLo) / range * (NBUCKET - 1) + 0.5) : NBUCKET - 1;
      buckets[Math.min(NBUCKET - 1, Math.max(0, b))].push(i);
    }
    view.colorRange = [vLo, vHi];
    legend();
    const stroke = (list) => {
      g.beginPath();
      for (const i of list) { const [sx, sy] = startOf(i); g.moveTo(px(sx), py(sy)); g.lineTo(px(X[i]), py(Y[i])); }
      g.stroke();
    };
    if (hl.length) { g.setLineDash([]); g.lineWidth = 6; g.strokeStyle = 'rgba(255,0,170,0.35)'; stroke(hl); }
    g.lineWidth = 1.4; g.lineCap = 'round';
    buckets.forEach((list, b) => { if (list.length) { g.strokeStyle = bucketColor(b); stroke(list); } });
    g.setLineDash([4, 4]); g.lineWidth = 0.8; g.strokeStyle = 'rgba(120,120,120,0.8)'; stroke(travel); g.setLineDash([]);
    // the head at the inspected time, when it is on this layer
    const at = view.pinned !== null ? view.pinned : view.hover;
    if (at !== null) {
      const i = moveAt(at);
      if (LAYER[i] === view.layer) {
        const [sx, sy] = startOf(i);
        const fr = fractionAlong(i, at);
        g.fillStyle = '#e0006a';
        g.beginPath(); g.arc(px(sx + fr * (X[i] - sx)), py(sy + fr * (Y[i] - sy)), 4.5, 0, 2 * Math.PI); g.fill();
      }
    }
    view.pathSegments = count;
    view.highlighted = hl.length;
    $('gpv-layer').textContent = groupName(view.layer) + ', ' + count + ' segments';
  }
  function fractionAlong(i, t) {   // distance done / move length at time t
    const ps = pieces(i);
    let tot = 0, done = 0;
    for (const p of ps) {
      const dist = (tau) => {
        if (!p.vec) return tau * (p.v0 + tau * (0.5 * p.a0 + tau * p.j / 6));
        let s = 0; const m = 16;   // |v + aτ| has no short closed form: Simpson's rule is plenty for a marker
        for (let q = 0; q <= m; q++) {
          const w = q === 0 || q === m ? 1 : (q % 2 ? 4 : 2);
          s += w * evalPiece(p, tau * q / m)[0];
        }
        return s * tau / (3 * m);
      };
      tot += dist(p.dt);
      if (t >= p.t0 + p.dt) done += dist(p.dt); else if (t > p.t0) done += dist(t - p.t0);
    }
    return tot > 0 ? Math.min(1, Math.max(0, done / tot)) : 0;
  }
  function nearestSegment(mx, my) {
    if (!pathXf) return -1;
    const { sc, ox, oy, x0, y1 } = pathXf;
    const px = (x) => ox + (x - x0) * sc, py = (y) => oy + (y1 - y) * sc;
    let best = -1, bd = 64;   // within 8 px
    for (const [a, b] of layerRuns.get(view.layer) || []) {
      for (let i = a; i < b; i++) {
        const k = KIND[i];
        if (k !== KPRINT && k !== KTRAVEL) continue;
        const [sx, sy] = startOf(i);
        const ax = px(sx), ay = py(sy), bx = px(X[i]), by = py(Y[i]);
        const dx = bx - ax, dy = by - ay, L = dx * dx + dy * dy;
        const u = L > 0 ? Math.min(1, Math.max(0, ((mx - ax) * dx + (my - ay) * dy) / L)) : 0;
        const ex = ax + u * dx - mx, ey = ay + u * dy - my, d2 = ex * ex + ey * ey;
        if (d2 < bd) { bd = d2; best = i; }
      }
    }
    return best;
  }
  function legend() {
    const c = document.createElement('canvas');
    const g = sizeCanvas(c, 160, 10);
    for (let b = 0; b < NBUCKET; b++) { g.fillStyle = bucketColor(b); g.fillRect(b * 5, 0, 5, 10); }
    const el = $('gpv-legend');
    const [lo, hi] = view.colorRange || [0, vColorMax];
    const digits = hi - lo >= 10 ? 0 : (hi - lo >= 1 ? 1 : 2);
    el.textContent = 'speed (peak of each move) ' + lo.toFixed(digits) + ' ';
    el.appendChild(c);
    el.appendChild(document.createTextNode(' ' + hi.toFixed(digits) + ' mm/s (this ' + (BY_Z ? 'Z level' : 'layer')
      + '\'s range); ' + (CNC ? 'rapids (G0)' : 'travel') + ' dashed; pink: the selected time span'));
  }

  // ------------------------------------------------------------------------------------ layer bars
  const bars = META.layer_bars;
  // one palette with the PNG plots (gcodeplan/report/palette.py): features, then '(no feature)', 'waits'
  const barNames = META.features.concat(['(no feature)', 'waits']);
  const barColor = (c) => META.feature_colors[c] || '#999999';
  const barsCanvas = $('gpv-bars');
  let barsGeom = null;
  function drawBars() {
    const w = parseFloat(barsCanvas.style.width), h = parseFloat(barsCanvas.style.height);
    const g = barsCanvas.getContext('2d');
    g.clearRect(0, 0, w, h);
    const L = bars.layers.length;
    if (!L) return;
    const tot = bars.times.map((r) => r.reduce((a, b) => a + b, 0));
    const ymax = Math.max(...tot) || 1, bw = (w - 50) / L, base = h - 16;
    barsGeom = { bw: bw, left: 45 };
    g.font = '10px sans-serif'; g.fillStyle = '#555';
    g.fillText(ymax.toFixed(0) + ' s', 2, 10); g.fillText('0', 30, base);
    for (let k = 0; k < L; k++) {
      let y = base;
      const x = 45 + k * bw;
      bars.times[k].forEach((v, c) => {
        if (v <= 0) return;
        const hh = v / ymax * (base - 4);
        g.fillStyle = barColor(c); g.fillRect(x, y - hh, Math.max(bw - (bw > 3 ? 1 : 0), 0.6), hh); y -= hh;
      });
      if (bars.layers[k] === view.layer) { g.strokeStyle = '#e0006a'; g.lineWidth = 1.5; g.strokeRect(x - 1, 2, bw + 1, base - 2); }
    }
    g.fillStyle = '#555';
    g.fillText(groupName(bars.layers[0], true), 45, h - 3);
    const last = groupName(bars.layers[L - 1], true);
    g.fillText(last, w - 5 - g.measureText(last).width, h - 3);
  }
  function barsLegend() {
    const used = new Set();
    for (const r of bars.times) r.forEach((v, c) => { if (v > 0) used.add(c); });
    const el = $('gpv-barinfo');
    el.innerHTML = [...used].sort((a, b) => a - b).map((c) => '<span class="gpv-sw" style="background:' + barColor(c)
      + '"></span>' + esc(barNames[c])).join(' ');
    el.className = 'gpv-legend';
  }
  function layerSpan(ly) {
    const runs = layerRuns.get(ly);
    if (!runs) return null;
    return [T[runs[0][0]], T[runs[runs.length - 1][1]]];
  }

  // ------------------------------------------------------------------------------------ the API
  let plot = null, busy = false;
  function setTimeline(t0, t1) {
    if (!(t1 > t0)) { const c = 0.5 * (t0 + t1); t0 = c - 5e-4; t1 = c + 5e-4; }
    view.t0 = t0; view.t1 = t1;
    const cols = Math.max(200, Math.round(plot.bbox.width / (window.devicePixelRatio || 1)));
    const data = seriesFor(t0, t1, cols);
    busy = true;
    plot.batch(() => {
      plot.setData(data, true);
      plot.setScale('x', { min: t0, max: t1 });
    });
    busy = false;
    $('gpv-window').textContent = hms(t0) + ' – ' + hms(t1) + '  (' + (t1 - t0).toPrecision(4) + ' s, '
      + view.mode + ', ' + view.points + ' points)';
  }
  function zoomTo(t0, t1) {
    t0 = +t0; t1 = +t1;
    if (t1 < t0) [t0, t1] = [t1, t0];
    setTimeline(t0, t1);
    return api.state();
  }
  function showLayer(ly) {
    ly = +ly;
    if (!layerRuns.has(ly)) {   // the nearest layer that has moves
      let best = layers[0];
      for (const k of layers) if (Math.abs(k - ly) < Math.abs(best - ly)) best = k;
      ly = best;
    }
    view.layer = ly;
    $('gpv-slider').value = String(layers.indexOf(ly));
    drawPath();
    drawBars();
    return api.state();
  }
  function stepLayer(d) {
    const k = Math.min(layers.length - 1, Math.max(0, layers.indexOf(view.layer) + d));
    showLayer(layers[k]);
  }
  function pan(frac) {   // never past either end of the print
    const w = view.t1 - view.t0;
    let a = view.t0 + frac * w;
    a = Math.min(a, TEND - w);
    a = Math.max(a, 0);
    if (w >= TEND) { zoomTo(0, TEND); return; }
    zoomTo(a, a + w);
  }
  function zoomBy(f, at) {   // zooming out stops at the whole print
    const c = at === undefined ? 0.5 * (view.t0 + view.t1) : at;
    let a = c - (c - view.t0) * f, b = c + (view.t1 - c) * f;
    if (b - a >= TEND) { a = 0; b = TEND; }
    else if (a < 0) { b -= a; a = 0; } else if (b > TEND) { a -= b - TEND; b = TEND; }
    zoomTo(a, b);
  }
  const api = {
    state: () => ({ t0: view.t0, t1: view.t1, layer: view.layer, points: view.points, mode: view.mode,
                    drawn: view.drawn ? Object.assign({}, view.drawn) : null, pathSegments: view.pathSegments,
                    highlight: view.hl ? view.hl.slice() : null, highlighted: view.highlighted, moves: n, totalTime: TEND, layers: layers.slice() }),
    zoomTo: zoomTo,
    showLayer: showLayer,
    inspectAt: inspectAt,
    highlight: (t0, t1) => { view.hl = t0 === null || t0 === undefined ? null : [+t0, +t1]; drawPath(); return api.state(); },
    selectMove: (i) => selectMove(+i),
    // where the middle of move i's segment is drawn on the toolpath canvas (CSS px), for scripts and tests
    pathPoint: (i) => {
      const [sx, sy] = startOf(i), q = pathXf;
      return [q.ox + (0.5 * (sx + X[i]) - q.x0) * q.sc, q.oy + (q.y1 - 0.5 * (sy + Y[i])) * q.sc];
    },
    barsGeometry: () => Object.assign({}, barsGeom),
    // the time axis's tick labels: text, centre and width (CSS px), for scripts and tests
    ticks: () => {
      const ax = plot.axes[0], vals = ax._values || [], splits = ax._splits || [];
      const g = document.createElement('canvas').getContext('2d');
      g.font = '12px system-ui, -apple-system, "Segoe UI", Roboto, "Helvetica Neue", Arial, "Noto Sans", sans-serif';
      return vals.map((s, k) => ({ text: String(s), x: plot.valToPos(splits[k], 'x'), w: g.measureText(String(s)).width }));
    },
    timing: {}
  };
  function selectMove(i) {
    const a = T[i], b = T[i + 1], w = Math.max(5 * (b - a), 0.02);
    zoomTo(0.5 * (a + b) - 0.5 * w, 0.5 * (a + b) + 0.5 * w);
    view.hl = [a, b];
    view.pinned = 0.5 * (a + b);
    if (LAYER[i] !== view.layer) showLayer(LAYER[i]); else drawPath();
    const l = plot.valToPos(a, 'x'), r = plot.valToPos(b, 'x');
    plot.setSelect({ left: l, width: Math.max(1, r - l), top: 0, height: plot.bbox.height / (window.devicePixelRatio || 1) }, false);
    showInspector(inspectAt(view.pinned));
    return api.state();
  }

  // ------------------------------------------------------------------------------------ set-up
  function makePlot(width) {
    const opts = {
      width: width, height: 320,
      scales: { x: { time: false }, v: { auto: true }, a: { auto: true } },
      series: [
        { label: 'time', value: (u, v) => v === null ? '' : hms(v) },
        { label: 'speed (min–max per pixel)', scale: 'v', stroke: '#1f5fa8', width: 1.3, value: (u, v) => v === null ? '' : v.toFixed(2) },
        { label: 'speed (min)', scale: 'v', stroke: '#1f5fa8', width: 1, value: (u, v) => v === null ? '' : v.toFixed(2) },
        { label: 'requested feed', scale: 'v', stroke: '#f08a24', width: 1, dash: [5, 3], value: (u, v) => v === null ? '' : v.toFixed(2) },
        { label: 'feed (min)', scale: 'v', stroke: '#f08a24', width: 1, dash: [5, 3], show: true, value: (u, v) => v === null ? '' : v.toFixed(2) },
        { label: 'acceleration (min–max)', scale: 'a', stroke: 'rgba(46,158,68,0.6)', width: 1, value: (u, v) => v === null ? '' : v.toFixed(0) },
        { label: 'accel (min)', scale: 'a', stroke: 'rgba(46,158,68,0.6)', width: 1, value: (u, v) => v === null ? '' : v.toFixed(0) }
      ],
      bands: [{ series: [1, 2], fill: 'rgba(31,95,168,0.30)' }, { series: [5, 6], fill: 'rgba(46,158,68,0.10)' }],
      axes: [
        { values: fmtAxisT, space: axisSpaceT, size: 40 },
        { scale: 'v', label: 'speed, feed (mm/s)', size: 60 },
        { scale: 'a', side: 1, label: 'acceleration (mm/s²)', grid: { show: false }, size: 70 }
      ],
      legend: { live: false },
      cursor: {
        drag: { x: true, y: false, setScale: false },
        bind: { dblclick: () => () => { zoomTo(0, TEND); return null; } }
      },
      hooks: {
        setSelect: [(u) => {
          if (busy || u.select.width < 3) return;
          const a = u.posToVal(u.select.left, 'x'), b = u.posToVal(u.select.left + u.select.width, 'x');
          view.hl = [a, b];
          u.setSelect({ left: 0, width: 0, top: 0, height: 0 }, false);
          zoomTo(a, b);
          const i = moveAt(a);
          if (LAYER[i] !== view.layer) showLayer(LAYER[i]); else drawPath();
        }],
        setCursor: [(u) => {
          if (busy || u.cursor.left === undefined || u.cursor.left < 0 || view.pinned !== null) return;
          const t = u.posToVal(u.cursor.left, 'x');
          view.hover = t;
          showInspector(inspectAt(t));
          drawPath();
        }]
      }
    };
    const p = new uPlot(opts, [[0, 1], [0, 0], [0, 0], [null, null], [null, null], [0, 0], [0, 0]], $('gpv-timeline'));
    // the band's lower edges are drawn, not listed: one legend entry per quantity
    p.root.querySelectorAll('.u-legend .u-series').forEach((row) => { if (/\(min\)/.test(row.textContent)) row.style.display = 'none'; });
    p.over.addEventListener('wheel', (e) => {
      e.preventDefault();
      const t = p.posToVal(e.offsetX, 'x');
      if (e.shiftKey) pan(e.deltaY > 0 ? 0.2 : -0.2);
      else zoomBy(e.deltaY > 0 ? 1.4 : 1 / 1.4, t);
    }, { passive: false });
    p.over.addEventListener('click', (e) => {
      if (Math.abs(e.offsetX - (p._downX || e.offsetX)) > 2) return;
      const t = p.posToVal(e.offsetX, 'x');
      view.pinned = view.pinned === null ? t : null;
      if (view.pinned !== null) { showInspector(inspectAt(t)); drawPath(); }
    });
    p.over.addEventListener('mousedown', (e) => { p._downX = e.offsetX; });
    return p;
  }

  async function init() {
    const t_start = performance.now();
    $('gpv-title').textContent = META.name;
    $('gpv-sub').textContent = 'machine ' + META.machine + ', policy ' + META.policy + ', ' + META.mode
      + (J > 0 ? ' (jerk ' + J + ' mm/s³)' : '') + '; ' + n + ' moves, ' + hms(META.t_end)
      + (META.thin > 1 ? ' — a big program: each row here merges ' + META.thin + ' consecutive moves (of '
         + META.moves + '), so that the page stays small; the times and layer bars are exact' : '');
    await load();
    const t_decoded = performance.now();
    buildTree();
    indexLayers();
    const t_built = performance.now();
    const width = Math.max(600, Math.min(1700, root.clientWidth || 1200));
    plot = makePlot(width);
    sizeCanvas(canvas, Math.min(640, Math.max(360, Math.floor(width * 0.45))), 520);
    sizeCanvas(barsCanvas, width, 170);
    barsLegend();
    if (BY_Z) {
      $('gpv-bars-title').textContent = 'time per Z level, split by feature';
      $('gpv-group-label').textContent = 'Z level';
    }
    const slider = $('gpv-slider');
    slider.max = String(Math.max(0, layers.length - 1));
    slider.addEventListener('input', () => showLayer(layers[+slider.value]));
    canvas.addEventListener('click', (e) => {
      const r = canvas.getBoundingClientRect();
      const i = nearestSegment(e.clientX - r.left, e.clientY - r.top);
      if (i >= 0) selectMove(i);
    });
    barsCanvas.addEventListener('click', (e) => {
      if (!barsGeom) return;
      const r = barsCanvas.getBoundingClientRect();
      const k = Math.floor((e.clientX - r.left - barsGeom.left) / barsGeom.bw);
      if (k < 0 || k >= bars.layers.length) return;
      const ly = bars.layers[k];
      showLayer(ly);
      const sp = layerSpan(ly);
      if (sp) { view.hl = null; zoomTo(sp[0], sp[1]); drawPath(); }
    });
    barsCanvas.addEventListener('mousemove', (e) => {
      if (!barsGeom) return;
      const r = barsCanvas.getBoundingClientRect();
      const k = Math.floor((e.clientX - r.left - barsGeom.left) / barsGeom.bw);
      if (k < 0 || k >= bars.layers.length) return;
      const tot = bars.times[k].reduce((a, b) => a + b, 0);
      barsCanvas.title = groupName(bars.layers[k], true) + ': ' + hms(tot);
    });
    let inside = false;
    root.addEventListener('mouseenter', () => { inside = true; });
    root.addEventListener('mouseleave', () => { inside = false; });
    document.addEventListener('keydown', (e) => {
      if (!inside && !root.contains(document.activeElement)) return;
      if (e.target === slider || e.altKey || e.ctrlKey || e.metaKey) return;
      const k = e.key;
      if (k === 'PageUp' || k === 'ArrowUp') stepLayer(1);
      else if (k === 'PageDown' || k === 'ArrowDown') stepLayer(-1);
      else if (k === 'ArrowLeft') pan(-0.25);
      else if (k === 'ArrowRight') pan(0.25);
      else if (k === '+' || k === '=') zoomBy(1 / 1.5);
      else if (k === '-' || k === '_') zoomBy(1.5);
      else if (k === 'Home') zoomTo(0, TEND);
      else if (k === 'Escape') { view.pinned = null; view.hl = null; drawPath(); }
      else return;
      e.preventDefault();
    });
    $('gpv-all').addEventListener('click', () => zoomTo(0, TEND));
    $('gpv-left').addEventListener('click', () => pan(-0.25));
    $('gpv-right').addEventListener('click', () => pan(0.25));
    $('gpv-in').addEventListener('click', () => zoomBy(1 / 1.5));
    $('gpv-out').addEventListener('click', () => zoomBy(1.5));
    setTimeline(0, TEND);
    showLayer(layers.find((k) => k >= 0) ?? layers[0]);
    showInspector(inspectAt(0));
    const t_drawn = performance.now();
    api.timing = { decodeMs: t_decoded - t_start, buildMs: t_built - t_decoded, drawMs: t_drawn - t_built,
                   readyMs: t_drawn };
    $('gpv-status').textContent = '';
    document.documentElement.setAttribute('data-gcodeplan-ready', '1');
  }

  window.gcodeplanView = api;
  init().catch((err) => {
    $('gpv-status').textContent = 'the viewer could not start: ' + err;
    document.documentElement.setAttribute('data-gcodeplan-ready', 'error');
    throw err;
  });
})();
