// The viewer (input / sharp / refocused / split wipe / radius / depth / alpha, zoom, time slice,
// click-to-focus) and the timeline with the focus lanes.
#include <GLFW/glfw3.h>
#include <GL/gl.h>
#include <imgui.h>

#include <algorithm>
#include <cmath>

#include "studio_app.h"
#include "fit/fit_engine.h"
#include "fit/tensor_image.h"
#include "synth/synth.h"
#include "util/error.h"

namespace refocus {

namespace {
constexpr float kSideWidth = 380.0f;
constexpr float kTimelineHeight = 200.0f;

// Linear → sRGB RGBA8 for display.
std::vector<unsigned char> to_rgba8(const Image& img) {
    std::vector<unsigned char> px(static_cast<size_t>(img.width) * img.height * 4, 255);
    for (size_t i = 0; i < static_cast<size_t>(img.width) * img.height; ++i)
        for (int c = 0; c < 3; ++c) {
            float v = img.pixels[i * img.channels + std::min(c, img.channels - 1)];
            if (!std::isfinite(v)) v = 0.0f;
            px[i * 4 + c] = static_cast<unsigned char>(std::lround(linear_to_srgb(v) * 255.0f));
        }
    return px;
}

Image grey_to_rgb(const Image& g, float scale = 1.0f) {
    Image out(g.width, g.height, 3);
    for (size_t i = 0; i < static_cast<size_t>(g.width) * g.height; ++i)
        for (int c = 0; c < 3; ++c) out.pixels[i * 3 + c] = srgb_to_linear(g.pixels[i * g.channels] * scale);
    return out;
}
}  // namespace

bool Studio::view_current() const {
    return m_view && m_view->t == m_frame && !m_view_dirty && m_requested_frame < 0;
}

void Studio::set_frame(int t) {
    if (!m_source) return;
    const int n = m_source->frames();
    m_frame = ((t % n) + n) % n;
    m_view_dirty = true;
}

void Studio::end_frame_timing() {
    const double ms = (glfwGetTime() - m_frame_start) * 1000.0;
    if (++m_frames_drawn <= 5) return;  // start-up: fonts, shader compilation
    m_longest_frame_ms = std::max(m_longest_frame_ms, ms);
    if (m_worker->status().state == FitWorker::State::Fitting)
        m_longest_fit_frame_ms = std::max(m_longest_fit_frame_ms, ms);
}

void Studio::poll_worker() {
    if (!m_doc.is_open()) return;
    const FitWorker::Status st = m_worker->status();
    const bool fitted = st.state == FitWorker::State::Ready || st.state == FitWorker::State::Fitting ||
                        st.state == FitWorker::State::Paused;
    if (!fitted) return;
    const double now = glfwGetTime();
    // Atlases: on every version change when idle, at most every 2 s while fitting.
    const bool fitting = st.state == FitWorker::State::Fitting;
    if (st.snap.atlas_version != m_atlas_version && (!fitting || now - m_last_refresh_request > 2.0)) {
        m_last_refresh_request = now;
        m_atlas_version = st.snap.atlas_version;
        m_worker->request_atlases();
        m_requested_frame = -1;  // the frame must be rendered again too
        m_view_dirty = true;
    }
    if (auto a = m_worker->take_atlases()) {
        m_atlas_panel.set_bases(a->bg, a->fg);
        m_edit_version = -1;  // re-upload to the preview
        m_view_dirty = true;
    }
    if (m_view_dirty && m_requested_frame != m_frame) {
        m_worker->request_frame(m_frame);
        m_requested_frame = m_frame;
    }
    if (auto v = m_worker->take_frame()) {
        m_view = std::move(*v);
        if (m_view->t == m_requested_frame) m_requested_frame = -1;
        if (m_view->t == m_frame) refresh_view();
    }
    // Depth: needed by refocus, depth view, click-to-focus; fitted once per checkpoint.
    if (!m_depth_requested && !fitting) {
        m_worker->request_depth();
        m_depth_requested = true;
    }
    auto d = m_worker->depth();
    if (d != m_depth) {
        m_depth = d;
        m_view_dirty = true;
        if (m_view && m_view->t == m_frame) refresh_view();
    }
    if (!fitting && st.snap.atlas_version != m_atlas_version) m_depth_requested = false;
    if (m_edit_version != static_cast<int64_t>(m_doc.edits().bg.version() + m_doc.edits().fg.version())) {
        m_view_dirty = true;
        if (m_view && m_view->t == m_frame) refresh_view();
    }
}

Image Studio::preview_image(bool refocus) {
    if (!m_gl) throw Error("the GLSL preview is unavailable: " + m_gl_error);
    const FrameMaps& m = m_view->maps;
    const int64_t ev = m_doc.edits().bg.version() + m_doc.edits().fg.version();
    if (ev != m_edit_version) {
        // Edited atlases (paper Fig. 1): the composite pass samples them through every frame's UV.
        Image bg = m_doc.edits().bg.result();
        Image fg = m.fg.empty() ? Image() : m_doc.edits().fg.result();
        if (bg.empty()) return m.sharp;  // atlases not received yet
        m_gl->set_atlases(bg, fg);
        m_edit_version = ev;
    }
    m_gl->set_frame(m.uv_bg, m.uv_fg, m.alpha);
    PreviewLens lens;
    if (refocus) {
        lens = m_doc.focus().lens_at(m_frame, m_depth.get());
        if (m_depth) {
            m_gl->set_depth(m_depth->frame_depth(m_frame, m.uv_bg, m.uv_fg));
            // The gather window follows the largest radius this frame can have (the result is
            // the same as with the default bound, and small apertures render much faster).
            float lo = 1e30f, hi = -1e30f;
            auto range = [&](const Image& a, float off) {
                for (float v : a.pixels)
                    if (std::isfinite(v)) lo = std::min(lo, v + off), hi = std::max(hi, v + off);
            };
            range(m_depth->bg_atlas, 0.0f);
            if (m_depth->has_fg()) range(m_depth->fg_atlas, m_depth->fg_offset[m_frame]);
            if (lo <= hi) {
                const double r = lens.aperture * std::max(std::abs(hi - lens.focus), std::abs(lo - lens.focus));
                lens.max_radius = std::clamp(std::ceil(r) + 1.0, 1.0, lens.max_radius);
            }
        }
    }
    const double t0 = glfwGetTime();
    m_gl->render(lens);
    Image out = m_gl->read_result();  // waits for the GPU: the render's full cost
    m_last_preview_ms = (glfwGetTime() - t0) * 1000.0;
    return out;
}

Image Studio::view_image(ViewMode mode) {
    switch (mode) {
        case ViewMode::Input: return m_source->linear(m_frame);
        case ViewMode::Sharp:
        case ViewMode::Refocused:
            if (!m_view) return m_source->linear(m_frame);
            if (mode == ViewMode::Refocused && !m_depth) return preview_image(false);
            return preview_image(mode == ViewMode::Refocused);
        case ViewMode::Radius:
            if (!m_view) return m_source->linear(m_frame);
            return coc_heatmap(m_view->radius, 12.0);
        case ViewMode::Alpha:
            if (!m_view || m_view->maps.alpha.empty()) return Image(m_source->width(), m_source->height(), 3, 0.0f);
            return grey_to_rgb(m_view->maps.alpha);
        case ViewMode::Depth: {
            if (!m_view || !m_depth) return Image(m_source->width(), m_source->height(), 3, 0.0f);
            const FrameMaps& m = m_view->maps;
            Image g = m_depth->depth_map(m_frame, m.uv_bg, m.uv_fg, m.alpha);
            float lo = 1e30f, hi = -1e30f;
            for (float v : g.pixels) lo = std::min(lo, v), hi = std::max(hi, v);
            for (size_t i = 0; i < g.pixels.size(); ++i) g.pixels[i] = (g.pixels[i] - lo) / std::max(hi - lo, 1e-6f);
            return coc_heatmap(g, 1.0);
        }
        case ViewMode::Split: {
            Image a = view_image(m_split_a), b = view_image(m_split_b);
            if (!a.same_shape(b)) return a;
            const int cut = static_cast<int>(m_split * a.width);
            for (int y = 0; y < a.height; ++y)
                for (int x = cut; x < a.width; ++x)
                    for (int c = 0; c < 3; ++c) a.at(x, y, c) = b.at(x, y, c);
            for (int y = 0; y < a.height && cut < a.width; ++y)
                for (int c = 0; c < 3; ++c) a.at(cut, y, c) = 1.0f;  // the wipe line
            return a;
        }
    }
    return {};
}

void Studio::upload(unsigned& tex, const Image& img, int& w, int& h) {
    const auto px = to_rgba8(img);
    if (!tex) glGenTextures(1, &tex);
    glBindTexture(GL_TEXTURE_2D, tex);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, img.width, img.height, 0, GL_RGBA, GL_UNSIGNED_BYTE, px.data());
    w = img.width;
    h = img.height;
}

void Studio::refresh_view() {
    if (!m_source) return;
    try {
        upload(m_tex, view_image(m_mode), m_tex_w, m_tex_h);
    } catch (const std::exception& e) {
        upload(m_tex, m_source->linear(m_frame), m_tex_w, m_tex_h);
        m_info = e.what();
    }
    const bool needs_model = m_mode != ViewMode::Input;
    m_view_dirty = needs_model && !(m_view && m_view->t == m_frame);
    m_slice_dirty = true;
}

void Studio::rebuild_time_slice() {
    // One row over all frames (x → image column, y → frame): flicker shows as horizontal
    // streaks. The input's slice is read here; the sharp or refocused output's is rendered by the
    // worker (every frame's layers, and the CPU twin for refocus), then shown when it arrives.
    const int w = m_source->width(), n = m_source->frames();
    if (m_slice_row < 0 || m_slice_row >= m_source->height()) m_slice_row = m_source->height() / 2;
    const bool output = m_mode != ViewMode::Input && m_worker->has_engine();
    const bool refocus = output && m_depth &&
                         (m_mode == ViewMode::Refocused ||
                          (m_mode == ViewMode::Split && (m_split_a == ViewMode::Refocused ||
                                                         m_split_b == ViewMode::Refocused)));
    const int64_t edit_version = m_doc.edits().bg.version() + m_doc.edits().fg.version();
    std::string key = std::to_string(m_slice_row) + (output ? (refocus ? "/refocus/" : "/sharp/") : "/input/") +
                      std::to_string(m_atlas_version) + "/" + std::to_string(output ? edit_version : 0);
    if (refocus) key += m_doc.focus().to_json().dump();
    m_slice_dirty = false;
    if (key == m_slice_key) return;
    m_slice_key = key;
    if (!output) {
        Image s(w, n, 3);
        for (int t = 0; t < n; ++t) {
            Image f = m_source->linear(t);
            for (int x = 0; x < w; ++x)
                for (int c = 0; c < 3; ++c) s.at(x, t, c) = f.at(x, m_slice_row, std::min(c, f.channels - 1));
        }
        upload(m_slice_tex, s, m_slice_w, m_slice_h);
        m_slice_image = std::move(s);
        m_slice_label = "input";
        return;
    }
    auto job = std::make_shared<SliceJob>();
    job->key = key;
    m_slice_job = job;
    const int row = m_slice_row;
    std::shared_ptr<const DepthModel> depth = refocus ? m_depth : nullptr;
    const FocusTrack focus = m_doc.focus();
    // The artist's atlas edits, saved or not, as the viewer and the export show them.
    const Image bg_edit = m_doc.edits().bg.has_edits() ? m_doc.edits().bg.result() : Image();
    const Image fg_edit = m_doc.edits().fg.has_edits() ? m_doc.edits().fg.result() : Image();
    m_worker->post("time slice", [job, row, depth, focus, w, n, bg_edit, fg_edit](FitEngine* engine, const Project&) {
        if (!engine) return;
        torch::Tensor d_bg, d_fg;
        {
            std::lock_guard<std::mutex> lock(engine->model_mutex());
            auto delta = [](const Image& edit, const torch::Tensor& base) {
                if (edit.empty() || !base.defined()) return torch::Tensor();
                auto e = image_to_tensor(edit).narrow(0, 0, 3);
                if (e.sizes() != base.sizes()) return torch::Tensor();  // an atlas of another fit
                return (e - base).unsqueeze(0);
            };
            d_bg = delta(bg_edit, engine->model().atlas_bg());
            d_fg = delta(fg_edit, engine->model().atlas_fg());
        }
        Image s(w, n, 3);
        for (int t = 0; t < n; ++t) {
            const FrameMaps m = frame_maps(*engine, t, d_bg, d_fg);
            const Image f = depth ? render_refocused(m, *depth, t, focus.lens_at(t, depth.get()), 2) : m.sharp;
            for (int x = 0; x < w; ++x)
                for (int c = 0; c < 3; ++c) s.at(x, t, c) = f.at(x, row, c);
        }
        std::lock_guard<std::mutex> lk(job->mutex);
        job->image = std::move(s);
        job->done = true;
    });
}

void Studio::poll_time_slice() {
    if (!m_slice_job) return;
    std::lock_guard<std::mutex> lk(m_slice_job->mutex);
    if (!m_slice_job->done) return;
    if (m_slice_job->key == m_slice_key) {
        upload(m_slice_tex, m_slice_job->image, m_slice_w, m_slice_h);
        m_slice_image = std::move(m_slice_job->image);
        m_slice_label = m_slice_key.find("/refocus/") != std::string::npos ? "refocused" : "sharp";
    }
    m_slice_job.reset();
}

bool Studio::image_pixel(float sx, float sy, int& x, int& y) const {
    if (m_img_w <= 0 || !m_source) return false;
    const float u = (sx - m_img_x) / m_img_w, v = (sy - m_img_y) / m_img_h;
    if (u < 0 || u >= 1 || v < 0 || v >= 1) return false;
    x = static_cast<int>(u * m_source->width());
    y = static_cast<int>(v * m_source->height());
    return true;
}

void Studio::draw_viewer() {
    const ImGuiViewport* vp = ImGui::GetMainViewport();
    const ImVec2 pos = vp->WorkPos;
    const ImVec2 size(vp->WorkSize.x - kSideWidth, vp->WorkSize.y - kTimelineHeight);
    if (m_show_atlas) {
        ImGui::SetNextWindowPos(pos);
        ImGui::SetNextWindowSize(size);
        if (m_atlas_panel.draw()) {  // a stroke, an undo, an import: the document changed
            m_view_dirty = true;
            m_doc.mark_dirty();
        }
        return;
    }
    ImGui::SetNextWindowPos(pos);
    ImGui::SetNextWindowSize(size);
    ImGui::Begin("Viewer", nullptr,
                 ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_NoMove |
                     ImGuiWindowFlags_NoBringToFrontOnFocus | ImGuiWindowFlags_NoSavedSettings);
    if (busy_with_files()) {
        if (!m_save_as_dir.empty())
            ImGui::Text("Saving the project as %s: copying its files ...", m_save_as_dir.c_str());
        else
            ImGui::Text("Making the project %s: decoding the clip's frames ...", m_ingest_dir.c_str());
        ImGui::ProgressBar(static_cast<float>(m_worker->status().job_progress), ImVec2(400, 0));
        ImGui::End();
        return;
    }
    if (!m_source) {
        ImGui::TextWrapped(
            "No project open.\n\nFile > New from clip... makes a project from a video or an image "
            "sequence; File > Open... opens a project folder (try projects/sample after `refocus new "
            "projects/sample/input.mp4 -o out/sample`).");
        ImGui::End();
        return;
    }
    // Mode bar.
    int mode = static_cast<int>(m_mode);
    const char* names[] = {"Input", "Sharp", "Refocused", "Split", "Radius", "Depth", "Alpha"};
    for (int i = 0; i < 7; ++i) {
        if (i) ImGui::SameLine();
        if (ImGui::RadioButton(names[i], &mode, i)) {
            m_mode = static_cast<ViewMode>(mode);
            m_view_dirty = true;
            refresh_view();
        }
    }
    ImGui::SameLine();
    ImGui::SetNextItemWidth(110);
    ImGui::SliderFloat("zoom", &m_zoom, 0.0f, 8.0f, m_zoom == 0 ? "fit" : "%.2fx");
    ImGui::SameLine();
    if (ImGui::Checkbox("time slice", &m_time_slice)) m_slice_dirty = true;
    if (m_mode == ViewMode::Split) {
        int a = static_cast<int>(m_split_a), b = static_cast<int>(m_split_b);
        ImGui::SetNextItemWidth(110);
        bool ch = ImGui::Combo("left", &a, names, 7);
        ImGui::SameLine();
        ImGui::SetNextItemWidth(110);
        ch |= ImGui::Combo("right", &b, names, 7);
        ImGui::SameLine();
        ImGui::SetNextItemWidth(160);
        ch |= ImGui::SliderFloat("wipe", &m_split, 0.0f, 1.0f);
        if (ch && a != 3 && b != 3) {
            m_split_a = static_cast<ViewMode>(a);
            m_split_b = static_cast<ViewMode>(b);
            refresh_view();
        }
    }
    if (m_view_dirty && (m_mode == ViewMode::Input || (m_view && m_view->t == m_frame))) refresh_view();
    if (!m_tex) refresh_view();

    ImVec2 avail = ImGui::GetContentRegionAvail();
    const float slice_h = m_time_slice ? std::min(avail.y * 0.35f, 160.0f) : 0.0f;
    avail.y -= slice_h;
    const float scale = m_zoom > 0 ? m_zoom
                                   : std::min(avail.x / m_tex_w, std::max(avail.y, 1.0f) / m_tex_h);
    const ImVec2 isz(m_tex_w * scale, m_tex_h * scale);
    ImGui::BeginChild("image", avail, false,
                      ImGuiWindowFlags_HorizontalScrollbar | ImGuiWindowFlags_NoScrollWithMouse);
    const ImVec2 cur = ImGui::GetCursorScreenPos(), region = ImGui::GetContentRegionAvail();
    ImGui::SetCursorScreenPos(ImVec2(cur.x + std::max(0.0f, (region.x - isz.x) * 0.5f),
                                     cur.y + std::max(0.0f, (region.y - isz.y) * 0.5f)));
    const ImVec2 ip = ImGui::GetCursorScreenPos();
    ImGui::Image(reinterpret_cast<ImTextureID>(static_cast<intptr_t>(m_tex)), isz);
    m_img_x = ip.x, m_img_y = ip.y, m_img_w = isz.x, m_img_h = isz.y;
    if (ImGui::IsWindowHovered()) {
        // Wheel zooms (from "fit" on), middle or right drag pans.
        const ImGuiIO& io = ImGui::GetIO();
        if (io.MouseWheel != 0.0f)
            m_zoom = std::clamp((m_zoom > 0 ? m_zoom : scale) * std::pow(1.15f, io.MouseWheel), 0.1f, 16.0f);
        if (ImGui::IsMouseDragging(ImGuiMouseButton_Middle) || ImGui::IsMouseDragging(ImGuiMouseButton_Right)) {
            ImGui::SetScrollX(ImGui::GetScrollX() - io.MouseDelta.x);
            ImGui::SetScrollY(ImGui::GetScrollY() - io.MouseDelta.y);
        }
    }
    if (ImGui::IsItemHovered()) {
        int x, y;
        const ImVec2 mp = ImGui::GetMousePos();
        if (image_pixel(mp.x, mp.y, x, y)) {
            std::string tip = "pixel " + std::to_string(x) + ", " + std::to_string(y);
            if (m_depth && m_view && m_view->t == m_frame) {
                char b[64];
                std::snprintf(b, sizeof b, "\ninverse depth %.2f", m_depth->depth_at_pixel(m_frame, x, y, m_view->maps.uv_bg, m_view->maps.uv_fg, m_view->maps.alpha));
                tip += b;
            }
            if (m_pick_focus) tip += "\nclick: focus here at this frame";
            if (m_pick_track) tip += "\nclick: track this point";
            ImGui::SetTooltip("%s", tip.c_str());
            if (ImGui::IsMouseClicked(0)) {
                if (m_pick_focus) guarded([&] { focus_at_pixel(m_frame, x, y); });
                if (m_pick_track) guarded([&] { track_pixel(m_frame, x, y); });
                if (m_time_slice) {
                    m_slice_row = y;
                    m_slice_dirty = true;
                }
                m_pick_focus = m_pick_track = false;
            }
        }
    }
    if (m_time_slice) {
        // The row the slice is taken from.
        const float ry = ip.y + (m_slice_row + 0.5f) * isz.y / m_tex_h;
        ImGui::GetWindowDrawList()->AddLine(ImVec2(ip.x, ry), ImVec2(ip.x + isz.x, ry),
                                            IM_COL32(255, 200, 0, 160));
    }
    ImGui::EndChild();
    if (m_time_slice) {
        if (m_slice_dirty) rebuild_time_slice();
        poll_time_slice();
        ImGui::Text("time slice: %s row %d over %d frames%s (click the image to choose the row)",
                    m_slice_label.c_str(), m_slice_row, m_source->frames(),
                    m_slice_job ? ", rendering ..." : "");
        const float h = slice_h - ImGui::GetFrameHeightWithSpacing();
        ImGui::Image(reinterpret_cast<ImTextureID>(static_cast<intptr_t>(m_slice_tex)),
                     ImVec2(std::min(avail.x, h * m_slice_w / std::max(1, m_slice_h) * 3), h));
    }
    ImGui::End();
}

void Studio::draw_timeline() {
    const ImGuiViewport* vp = ImGui::GetMainViewport();
    ImGui::SetNextWindowPos(ImVec2(vp->WorkPos.x, vp->WorkPos.y + vp->WorkSize.y - kTimelineHeight));
    ImGui::SetNextWindowSize(ImVec2(vp->WorkSize.x - kSideWidth, kTimelineHeight));
    ImGui::Begin("Timeline", nullptr,
                 ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoResize | ImGuiWindowFlags_NoCollapse |
                     ImGuiWindowFlags_NoSavedSettings);
    if (!m_source) {
        ImGui::End();
        return;
    }
    const int n = m_source->frames();
    if (ImGui::Button(m_playing ? "Pause" : "Play")) {
        m_playing = !m_playing;
        m_play_clock = glfwGetTime();
    }
    ImGui::SameLine();
    if (ImGui::ArrowButton("prev", ImGuiDir_Left)) set_frame(m_frame - 1);
    ImGui::SameLine();
    if (ImGui::ArrowButton("next", ImGuiDir_Right)) set_frame(m_frame + 1);
    ImGui::SameLine();
    ImGui::SetNextItemWidth(-1);
    int f = m_frame;
    if (ImGui::SliderInt("##frame", &f, 0, n - 1, "frame %d")) set_frame(f);
    if (m_playing) {
        const double now = glfwGetTime();
        const int steps = static_cast<int>((now - m_play_clock) * m_source->fps());
        if (steps > 0) {
            set_frame((m_frame + steps) % n);
            m_play_clock += steps / m_source->fps();
        }
    }
    // Lanes: one row per focus parameter, keyframes as diamonds. Click a row to move the
    // playhead; right-click a diamond to delete it.
    ImDrawList* dl = ImGui::GetWindowDrawList();
    const float label_w = 110.0f, row_h = 18.0f;
    const ImVec2 origin = ImGui::GetCursorScreenPos();
    const float lane_w = ImGui::GetContentRegionAvail().x - label_w;
    auto frame_x = [&](double fr) { return origin.x + label_w + (fr + 0.5) / n * lane_w; };
    const auto& lanes = focus_lanes();
    for (size_t i = 0; i < lanes.size(); ++i) {
        const float y = origin.y + i * row_h;
        dl->AddText(ImVec2(origin.x, y + 2), IM_COL32(200, 200, 200, 255), lanes[i].name);
        dl->AddRectFilled(ImVec2(origin.x + label_w, y + 1), ImVec2(origin.x + label_w + lane_w, y + row_h - 1),
                          IM_COL32(40, 40, 46, 255));
        Lane& lane = m_doc.focus().*(lanes[i].lane);
        for (const Keyframe& k : lane.keys) {
            const float cx = frame_x(k.frame), cy = y + row_h * 0.5f, r = 5.0f;
            dl->AddQuadFilled(ImVec2(cx, cy - r), ImVec2(cx + r, cy), ImVec2(cx, cy + r), ImVec2(cx - r, cy),
                              IM_COL32(240, 190, 60, 255));
        }
    }
    if (m_doc.focus().track) {
        const auto& tr = *m_doc.focus().track;
        const float y = origin.y + 0.5f * row_h;
        dl->AddLine(ImVec2(frame_x(tr.from_frame), y), ImVec2(frame_x(tr.to_frame), y),
                    IM_COL32(90, 200, 255, 200), 3.0f);
    }
    const float total_h = lanes.size() * row_h;
    dl->AddLine(ImVec2(frame_x(m_frame), origin.y), ImVec2(frame_x(m_frame), origin.y + total_h),
                IM_COL32(255, 80, 80, 255), 2.0f);
    ImGui::SetCursorScreenPos(ImVec2(origin.x + label_w, origin.y));
    ImGui::InvisibleButton("lanes", ImVec2(std::max(lane_w, 1.0f), total_h));
    if (ImGui::IsItemHovered()) {
        const ImVec2 mp = ImGui::GetMousePos();
        const int fr = std::clamp(static_cast<int>((mp.x - origin.x - label_w) / lane_w * n), 0, n - 1);
        const int row = static_cast<int>((mp.y - origin.y) / row_h);
        if (ImGui::IsMouseDown(0)) set_frame(fr);
        if (ImGui::IsMouseClicked(1) && row >= 0 && row < static_cast<int>(lanes.size())) {
            Lane& lane = m_doc.focus().*(lanes[row].lane);
            for (const Keyframe& k : lane.keys)
                if (std::abs(frame_x(k.frame) - mp.x) < 6.0f) {
                    lane.remove(k.frame);
                    m_doc.mark_dirty();
                    m_view_dirty = true;
                    break;
                }
        }
    }
    ImGui::End();
}

}  // namespace refocus
