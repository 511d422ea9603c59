#include "edit/atlas_edit.h"

#include <torch/torch.h>

#include <algorithm>
#include <cmath>

#include "io/tensor_image.h"
#include "util/error.h"

namespace refocus {

namespace F = torch::nn::functional;

float dab_coverage(float d, float size, float hardness) {
    const float R = std::max(0.5f, 0.5f * size), h = std::clamp(hardness, 0.0f, 1.0f);
    const float edge = std::clamp(R + 0.5f - d, 0.0f, 1.0f);  // 1 px anti-aliased rim
    const float inner = h * R;
    if (d <= inner || h >= 1.0f) return edge;
    const float t = std::clamp((d - inner) / (R - inner), 0.0f, 1.0f);
    return std::min(edge, 1.0f - t * t * (3.0f - 2.0f * t));  // smoothstep falloff
}

// ---------------------------------------------------------------- AtlasEditor basics
void AtlasEditor::Rect::add(const Rect& o) {
    if (o.empty()) return;
    if (empty()) {
        *this = o;
        return;
    }
    x0 = std::min(x0, o.x0), y0 = std::min(y0, o.y0), x1 = std::max(x1, o.x1),
    y1 = std::max(y1, o.y1);
}

namespace {
[[noreturn]] void size_error(const std::string& label, int ew, int eh, const char* what, int w,
                             int h) {
    throw Error(file_error(label.empty() ? "atlas edit" : label,
                           "the edit is " + std::to_string(ew) + "x" + std::to_string(eh) +
                               " but " + what + " is " + std::to_string(w) + "x" +
                               std::to_string(h) + " (clear it: refocus atlas <project> --clear)"));
}
}  // namespace

void AtlasEditor::check_size(int w, int h, const char* what) const {
    if (w != m_edit.width || h != m_edit.height)
        size_error(m_label, m_edit.width, m_edit.height, what, w, h);
}

namespace {
// An edit carried to an atlas of twice or half its resolution over the same scene (a refit that
// chose the other atlas scale, choose_atlas_scale): texel centres sit at the same atlas
// coordinates in [-1, 1] at either size, so the straight-alpha layer is resampled premultiplied,
// bilinearly up or by 2x2 means down.
Image rescale_edit(const Image& e, int w, int h) {
    auto t = image_to_tensor(e).unsqueeze(0);  // [1,4,H,W]
    auto a = t.narrow(1, 3, 1);
    auto pm = torch::cat({t.narrow(1, 0, 3) * a, a}, 1);
    auto opts = F::InterpolateFuncOptions().size(std::vector<int64_t>{h, w});
    pm = w > e.width ? F::interpolate(pm, opts.mode(torch::kBilinear).align_corners(false))
                     : F::interpolate(pm, opts.mode(torch::kArea));
    auto na = pm.narrow(1, 3, 1);
    auto rgb = torch::where(na > 1e-6, pm.narrow(1, 0, 3) / na.clamp_min(1e-6),
                            torch::zeros_like(pm.narrow(1, 0, 3)));
    return tensor_to_image(torch::cat({rgb, na.clamp(0, 1)}, 1)[0].contiguous());
}
}  // namespace

void AtlasEditor::set_base(const Image& base) {
    if (base.empty()) throw Error("atlas editor: empty base atlas");
    Image b = base.channels == 3 ? base : to_rgb(base);
    if (m_edit.empty() ||
        ((b.width != m_edit.width || b.height != m_edit.height) && !has_edits())) {
        end_stroke();
        m_edit = Image(b.width, b.height, 4, 0.0f);
        m_undo.clear(), m_redo.clear(), m_history_bytes = 0;
    } else if ((b.width == 2 * m_edit.width && b.height == 2 * m_edit.height) ||
               (2 * b.width == m_edit.width && 2 * b.height == m_edit.height)) {
        end_stroke();
        m_edit = rescale_edit(m_edit, b.width, b.height);
        m_undo.clear(), m_redo.clear(), m_history_bytes = 0;
    }
    check_size(b.width, b.height, "the fitted atlas");
    m_base = std::move(b);
    ++m_version;
}

bool AtlasEditor::has_edits() const {
    if (m_has_version != m_version) {
        m_has = false;
        for (size_t i = 3; i < m_edit.size() && !m_has; i += 4) m_has = m_edit.pixels[i] > 0.0f;
        m_has_version = m_version;
    }
    return m_has;
}

std::array<float, 3> AtlasEditor::result_at(int x, int y, bool pre_stroke) const {
    const size_t i = size_t(y) * m_edit.width + x;
    const bool before = pre_stroke && m_in_stroke && m_cov[i] > 0.0f;
    const float* e = (before ? m_before.data() : m_edit.data()) + 4 * i;
    std::array<float, 3> out;
    for (int c = 0; c < 3; ++c) {
        const float b = m_base.empty() ? 0.0f : m_base.pixels[3 * i + c];
        out[c] = b * (1.0f - e[3]) + e[c] * e[3];
    }
    return out;
}

Image AtlasEditor::result() const {
    if (m_base.empty()) throw Error("atlas editor: no fitted atlas yet");
    Image out(m_base.width, m_base.height, 3);
    for (int y = 0; y < out.height; ++y)
        for (int x = 0; x < out.width; ++x) {
            auto px = result_at(x, y, false);
            std::copy(px.begin(), px.end(), &out.at(x, y, 0));
        }
    return out;
}

std::array<float, 3> AtlasEditor::pick(float x, float y) const {
    if (m_edit.empty()) throw Error("atlas editor: no atlas yet");
    return result_at(std::clamp(int(std::floor(x)), 0, m_edit.width - 1),
                     std::clamp(int(std::floor(y)), 0, m_edit.height - 1), false);
}

// ---------------------------------------------------------------- history
std::vector<float> AtlasEditor::crop(const Image& img, const Rect& r) const {
    std::vector<float> out;
    out.reserve(size_t(r.x1 - r.x0) * (r.y1 - r.y0) * 4);
    for (int y = r.y0; y < r.y1; ++y) {
        const float* row = img.data() + (size_t(y) * img.width + r.x0) * 4;
        out.insert(out.end(), row, row + 4 * (r.x1 - r.x0));
    }
    return out;
}

void AtlasEditor::paste(Image& img, const Rect& r, const std::vector<float>& px) {
    const size_t row = 4 * size_t(r.x1 - r.x0);
    for (int y = r.y0; y < r.y1; ++y)
        std::copy_n(px.data() + (y - r.y0) * row, row, &img.at(r.x0, y, 0));
}

void AtlasEditor::push_step(Step s) {
    for (const Step& r : m_redo) m_history_bytes -= r.bytes();
    m_redo.clear();
    m_history_bytes += s.bytes();
    m_undo.push_back(std::move(s));
    set_undo_limit(m_history_limit);
}

void AtlasEditor::set_undo_limit(size_t bytes) {
    m_history_limit = bytes;
    while (m_history_bytes > m_history_limit && !m_undo.empty()) {
        m_history_bytes -= m_undo.front().bytes();
        m_undo.pop_front();
    }
}

void AtlasEditor::undo() {
    if (m_in_stroke) end_stroke();
    if (m_undo.empty()) return;
    Step s = std::move(m_undo.back());
    m_undo.pop_back();
    paste(m_edit, s.r, s.before);
    m_redo.push_back(std::move(s));
    ++m_version;
}

void AtlasEditor::redo() {
    if (m_in_stroke) end_stroke();
    if (m_redo.empty()) return;
    Step s = std::move(m_redo.back());
    m_redo.pop_back();
    paste(m_edit, s.r, s.after);
    m_undo.push_back(std::move(s));
    ++m_version;
}

void AtlasEditor::replace_edit(Image next) {
    if (m_in_stroke) end_stroke();
    Rect r;
    for (int y = 0; y < next.height; ++y)
        for (int x = 0; x < next.width; ++x)
            if (!std::equal(&next.at(x, y, 0), &next.at(x, y, 0) + 4, &m_edit.at(x, y, 0)))
                r.add({x, y, x + 1, y + 1});
    if (r.empty()) return;
    Step s{r, crop(m_edit, r), crop(next, r)};
    m_edit = std::move(next);
    push_step(std::move(s));
    ++m_version;
}

void AtlasEditor::clear() {
    if (!m_edit.empty()) replace_edit(Image(m_edit.width, m_edit.height, 4, 0.0f));
}

// ---------------------------------------------------------------- strokes
void AtlasEditor::begin_stroke(const Brush& brush) {
    if (m_edit.empty()) throw Error("atlas editor: no atlas yet");
    if (m_in_stroke) end_stroke();
    if (brush.mode == Brush::Clone && m_base.empty())
        throw Error("atlas editor: cloning needs the fitted atlas");
    m_brush = brush;
    m_brush.size = std::max(m_brush.size, 0.5f);
    m_brush.opacity = std::clamp(m_brush.opacity, 0.0f, 1.0f);
    const size_t n = size_t(m_edit.width) * m_edit.height;
    if (m_cov.size() != n) m_cov.assign(n, 0.0f);
    if (!m_before.same_shape(m_edit)) m_before = Image(m_edit.width, m_edit.height, 4);
    m_in_stroke = true;
    m_have_last = false;
    m_carry = 0;
    m_dirty = Rect{};
}

void AtlasEditor::stroke_pixel(int x, int y, float cov) {
    const size_t i = size_t(y) * m_edit.width + x;
    if (cov <= m_cov[i]) return;  // max within a stroke: overlapping dabs do not build up
    float col[3] = {m_brush.color[0], m_brush.color[1], m_brush.color[2]};
    if (m_brush.mode == Brush::Clone) {
        // Bilinear source from the result before this stroke; none outside the atlas.
        const float sx = x + m_brush.clone_dx, sy = y + m_brush.clone_dy;
        if (sx < 0 || sy < 0 || sx > m_edit.width - 1 || sy > m_edit.height - 1) return;
        const int x0 = int(sx), y0 = int(sy);
        const int x1 = std::min(x0 + 1, m_edit.width - 1), y1 = std::min(y0 + 1, m_edit.height - 1);
        const float fx = sx - x0, fy = sy - y0;
        auto a = result_at(x0, y0, true), b = result_at(x1, y0, true);
        auto c = result_at(x0, y1, true), d = result_at(x1, y1, true);
        for (int k = 0; k < 3; ++k)
            col[k] = (a[k] * (1 - fx) + b[k] * fx) * (1 - fy) + (c[k] * (1 - fx) + d[k] * fx) * fy;
    }
    float* e = &m_edit.at(x, y, 0);
    float* b = &m_before.at(x, y, 0);
    if (m_cov[i] == 0.0f) {
        std::copy_n(e, 4, b);
        m_dirty.add({x, y, x + 1, y + 1});
    }
    m_cov[i] = cov;
    if (m_brush.mode == Brush::Erase) {
        e[3] = b[3] * (1.0f - cov);
        for (int k = 0; k < 3; ++k) e[k] = e[3] > 0.0f ? b[k] : 0.0f;
        return;
    }
    const float a = cov + b[3] * (1.0f - cov);  // "over", straight alpha
    for (int k = 0; k < 3; ++k)
        e[k] = a > 0.0f ? (col[k] * cov + b[k] * b[3] * (1.0f - cov)) / a : 0.0f;
    e[3] = a;
}

void AtlasEditor::dab(float cx, float cy) {
    if (!m_in_stroke) begin_stroke(m_brush);
    const float R = 0.5f * m_brush.size + 1.0f;
    Rect r{std::max(0, int(std::floor(cx - R))), std::max(0, int(std::floor(cy - R))),
           std::min(m_edit.width, int(std::ceil(cx + R)) + 1),
           std::min(m_edit.height, int(std::ceil(cy + R)) + 1)};
    for (int y = r.y0; y < r.y1; ++y)
        for (int x = r.x0; x < r.x1; ++x) {
            const float d = std::hypot(x + 0.5f - cx, y + 0.5f - cy);
            const float cov = m_brush.opacity * dab_coverage(d, m_brush.size, m_brush.hardness);
            if (cov > 0.0f) stroke_pixel(x, y, cov);
        }
    m_last_x = cx, m_last_y = cy, m_have_last = true;
    ++m_version;
}

void AtlasEditor::stroke_to(float x, float y) {
    if (!m_in_stroke || !m_have_last) {
        dab(x, y);
        m_carry = 0;
        return;
    }
    const float sx = m_last_x, sy = m_last_y, dist = std::hypot(x - sx, y - sy);
    if (dist <= 0.0f) return;
    const float spacing = std::max(0.25f, 0.25f * m_brush.size);
    float pos = spacing - m_carry;
    for (; pos <= dist; pos += spacing) dab(sx + (x - sx) * pos / dist, sy + (y - sy) * pos / dist);
    m_carry = dist - (pos - spacing);
    m_last_x = x, m_last_y = y;
}

void AtlasEditor::end_stroke() {
    if (!m_in_stroke) return;
    m_in_stroke = false;
    const Rect r = m_dirty;
    if (r.empty()) return;
    Step s{r, {}, crop(m_edit, r)};
    s.before.reserve(s.after.size());
    for (int y = r.y0; y < r.y1; ++y)
        for (int x = r.x0; x < r.x1; ++x) {
            float& cov = m_cov[size_t(y) * m_edit.width + x];
            const float* src = cov > 0.0f ? &m_before.at(x, y, 0) : &m_edit.at(x, y, 0);
            s.before.insert(s.before.end(), src, src + 4);
            cov = 0.0f;
        }
    push_step(std::move(s));
}

// ---------------------------------------------------------------- files
int64_t AtlasEditor::import_image(const std::string& path) {
    if (m_base.empty()) throw Error(file_error(path, "no fitted atlas to import over"));
    ImageReadResult r =
        read_image_file(path, true, NonFinitePolicy::Reject, -1,
                        "save the repainted atlas again without NaN/Inf or extreme values");
    const Image img = to_rgb(r.image);
    if (img.width != m_base.width || img.height != m_base.height)
        throw Error(file_error(path, "the image is " + std::to_string(img.width) + "x" +
                                         std::to_string(img.height) + " but the atlas is " +
                                         std::to_string(m_base.width) + "x" +
                                         std::to_string(m_base.height)));
    // Compare in sRGB, where 1/255 is one code value; integer files cannot hold values above 1,
    // so there the base is compared clamped (HDR atlas texels survive a PNG round trip).
    const bool hdr = r.format == "half" || r.format == "float";
    auto enc = [hdr](float v) { return hdr && v > 1.0f ? v : linear_to_srgb(v); };
    Image next(img.width, img.height, 4, 0.0f);
    int64_t n = 0;
    for (size_t i = 0; i < size_t(img.width) * img.height; ++i) {
        bool differs = false;
        for (int c = 0; c < 3; ++c)
            differs |=
                std::abs(enc(img.pixels[3 * i + c]) - enc(m_base.pixels[3 * i + c])) > 0.75f / 255;
        if (!differs) continue;
        std::copy_n(&img.pixels[3 * i], 3, &next.pixels[4 * i]);
        next.pixels[4 * i + 3] = 1.0f;
        ++n;
    }
    replace_edit(std::move(next));
    return n;
}

void AtlasEditor::export_image(const std::string& path, PixelFormat format) const {
    write_image_file(path, result(), format);
}

void AtlasEditor::load_edit(const std::string& path) {
    Image e = read_image_file(path, false).image;
    m_label = path;
    if (e.channels != 4)
        throw Error(file_error(
            path, "an atlas edit must be RGBA (has " + std::to_string(e.channels) + " channels)"));
    if (!m_base.empty() && (e.width != m_base.width || e.height != m_base.height))
        size_error(path, e.width, e.height, "the fitted atlas", m_base.width, m_base.height);
    end_stroke();
    m_edit = std::move(e);
    m_undo.clear(), m_redo.clear(), m_history_bytes = 0;
    ++m_version;
}

void AtlasEditor::save_edit(const std::string& path) const {
    if (m_edit.empty()) throw Error(file_error(path, "no edit to save"));
    write_image_file(path, m_edit, PixelFormat::ExrFloat);
}

torch::Tensor AtlasEditor::delta(const torch::Tensor& base) const {
    if (!has_edits()) return {};
    check_size(int(base.size(2)), int(base.size(1)), "the fitted atlas");
    auto e = image_to_tensor(m_edit);
    auto a = e.narrow(0, 3, 1);
    return (a * (e.narrow(0, 0, 3) - base)).unsqueeze(0);
}

// ---------------------------------------------------------------- project files
namespace {
const char* kLayerName[2] = {"bg", "fg"};
}

fs::path ProjectEdits::file_of(const Project& p, int layer) {
    return p.dir / "edits" / (std::string("edit_") + kLayerName[layer] + ".exr");
}

ProjectEdits ProjectEdits::load(const Project& p) {
    ProjectEdits out;
    const nlohmann::json* sec = p.sections.contains("edits") ? &p.sections.at("edits") : nullptr;
    if (sec && !sec->is_object())
        throw Error(file_error(p.project_file().string(), "field 'edits' must be an object"));
    for (int i = 0; i < 2; ++i) {
        fs::path f = file_of(p, i);
        if (sec) {
            if (!sec->contains(kLayerName[i])) continue;
            const auto& v = sec->at(kLayerName[i]);
            if (!v.is_string())
                throw Error(file_error(
                    p.project_file().string(),
                    std::string("field 'edits.") + kLayerName[i] + "' must be a string"));
            f = p.dir / v.get<std::string>();
        }
        if (fs::exists(f))
            out.layer(i).load_edit(f.string());
        else
            out.layer(i).m_label = f.string();
    }
    return out;
}

void ProjectEdits::save(Project& p) const {
    save_layers(p, bg.has_edits() ? &bg.edit() : nullptr, fg.has_edits() ? &fg.edit() : nullptr);
}

void ProjectEdits::save_layers(Project& p, const Image* bg_edit, const Image* fg_edit) {
    nlohmann::json sec = nlohmann::json::object();
    for (int i = 0; i < 2; ++i) {
        const fs::path f = file_of(p, i);
        if (const Image* e = i == 0 ? bg_edit : fg_edit) {
            fs::create_directories(f.parent_path());
            write_image_file(f.string(), *e, PixelFormat::ExrFloat);
            sec[kLayerName[i]] = f.lexically_relative(p.dir).string();
        } else {
            std::error_code ec;
            fs::remove(f, ec);
        }
    }
    p.sections["edits"] = sec;
    p.save_merged({"edits"});
}

// ---------------------------------------------------------------- frames
void apply_edits(Layers& L, const torch::Tensor& bg_delta, const torch::Tensor& fg_delta) {
    if (!bg_delta.defined() && !fg_delta.defined()) return;
    torch::NoGradGuard g;
    const auto opts = F::GridSampleFuncOptions()
                          .mode(torch::kBilinear)
                          .padding_mode(torch::kBorder)
                          .align_corners(false);
    auto through = [&](const torch::Tensor& d, const torch::Tensor& uv, const char* layer) {
        if (!uv.defined())
            throw Error(std::string("atlas edits: this fit has no ") + layer +
                        " atlas mapping (perframe preset or one layer)");
        return F::grid_sample(d.expand({uv.size(0), 3, d.size(2), d.size(3)}), uv, opts);
    };
    if (bg_delta.defined()) L.bg = L.bg + through(bg_delta, L.uv_bg, "background");
    if (fg_delta.defined()) L.fg = L.fg + through(fg_delta, L.uv_fg, "foreground");
    L.sharp = L.fg.defined() ? L.alpha * L.fg + (1.0 - L.alpha) * L.bg : L.bg;  // paper eq. 1
}

}  // namespace refocus
