#include "atlas_panel.h"

#include <GL/gl.h>
#include <imgui.h>

#include <algorithm>
#include <cctype>
#include <cmath>

namespace refocus {

namespace {
const char* kLayerLabel[2] = {"Background", "Foreground"};
const PixelFormat kExportFormats[3] = {PixelFormat::Png8, PixelFormat::Tiff16,
                                       PixelFormat::ExrHalf};
const char* kExportNames[3] = {"PNG", "TIFF 16", "EXR"};
const char* kExportExts[3] = {".png", ".tif", ".exr"};

// The export format a file name asks for (its extension); -1 when it names none of them.
int format_of_name(const fs::path& p) {
    std::string e = p.extension().string();
    for (char& c : e) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    if (e == ".png") return 0;
    if (e == ".tif" || e == ".tiff") return 1;
    if (e == ".exr") return 2;
    return -1;
}
}  // namespace

AtlasPanel::~AtlasPanel() {
    for (unsigned& t : m_tex)
        if (t) glDeleteTextures(1, &t), t = 0;
}

void AtlasPanel::set_edits(ProjectEdits* edits) {
    m_edits = edits;
    // The edits as given (loaded with the project) are no change to report.
    for (int i = 0; i < 2; ++i) m_reported[i] = edits ? edits->layer(i).version() : -1;
    m_tex_version[0] = m_tex_version[1] = -1;
}

AtlasEditor* AtlasPanel::editor(int layer) {
    if (!m_edits || layer < 0 || layer > 1) return nullptr;
    return &m_edits->layer(layer);
}

bool AtlasPanel::guarded(const std::function<void()>& f) {
    try {
        f();
        m_error.clear();
        return true;
    } catch (const std::exception& e) {
        m_error = e.what();
        return false;
    }
}

void AtlasPanel::set_bases(const Image& bg, const Image& fg) {
    if (!m_edits) return;
    const Image* base[2] = {&bg, &fg};
    for (int i = 0; i < 2; ++i) {
        if (base[i]->empty()) continue;
        AtlasEditor& ed = m_edits->layer(i);
        // A new base is no edit, with or without paint over it (the caller re-uploads its
        // atlases when they arrive); only an edit not yet reported stays to report.
        const bool up_to_date = m_reported[i] == ed.version();
        guarded([&] { ed.set_base(*base[i]); });
        if (up_to_date) m_reported[i] = ed.version();
    }
}

bool AtlasPanel::paint_stroke(int layer, const std::vector<std::array<float, 2>>& pts,
                              const Brush& brush) {
    AtlasEditor* ed = editor(layer);
    if (!ed || pts.empty()) return false;
    return guarded([&] {
        ed->begin_stroke(brush);
        ed->dab(pts[0][0], pts[0][1]);
        for (size_t i = 1; i < pts.size(); ++i) ed->stroke_to(pts[i][0], pts[i][1]);
        ed->end_stroke();
    });
}

bool AtlasPanel::import_atlas(int layer, const std::string& path) {
    AtlasEditor* ed = editor(layer);
    return ed && guarded([&] { ed->import_image(path); });
}

bool AtlasPanel::export_atlas(int layer, const std::string& path, PixelFormat format) {
    AtlasEditor* ed = editor(layer);
    return ed && guarded([&] { ed->export_image(path, format); });
}

bool AtlasPanel::undo(int layer) {
    AtlasEditor* ed = editor(layer);
    if (!ed || !ed->can_undo()) return false;
    ed->undo();
    return true;
}

bool AtlasPanel::redo(int layer) {
    AtlasEditor* ed = editor(layer);
    if (!ed || !ed->can_redo()) return false;
    ed->redo();
    return true;
}

void AtlasPanel::upload(int layer) {
    AtlasEditor& ed = m_edits->layer(layer);
    if (m_tex_version[layer] == ed.version() || ed.base().empty()) return;
    const Image res = ed.result();
    std::vector<unsigned char> px(size_t(res.width) * res.height * 4, 255);
    for (size_t i = 0; i < size_t(res.width) * res.height; ++i)
        for (int c = 0; c < 3; ++c) px[4 * i + c] = linear_to_srgb8(res.pixels[3 * i + c]);
    if (!m_tex[layer]) glGenTextures(1, &m_tex[layer]);
    glBindTexture(GL_TEXTURE_2D, m_tex[layer]);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);  // texels when zoomed in
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, res.width, res.height, 0, GL_RGBA, GL_UNSIGNED_BYTE,
                 px.data());
    m_tex_version[layer] = ed.version();
}

void AtlasPanel::draw_controls(AtlasEditor& ed) {
    ImGui::SetNextItemWidth(180);
    ImGui::ColorEdit3("colour", m_brush.color, ImGuiColorEditFlags_Float | ImGuiColorEditFlags_HDR);
    item_tooltip("The brush colour, linear light (values above 1 paint highlights)");
    ImGui::SameLine();
    if (ImGui::Button(m_picking ? "Picking... (I)" : "Pick (I)")) m_picking = !m_picking;
    item_tooltip("Eyedropper: the next click on the atlas takes its colour");
    ImGui::SetNextItemWidth(180);
    ImGui::SliderFloat("size", &m_brush.size, 1.0f, 256.0f, "%.0f px",
                       ImGuiSliderFlags_Logarithmic);
    item_tooltip("Brush diameter in atlas pixels ([ and ] too)");
    ImGui::SameLine();
    ImGui::SetNextItemWidth(120);
    ImGui::SliderFloat("hardness", &m_brush.hardness, 0.0f, 1.0f, "%.2f");
    item_tooltip("0: soft falloff from the centre, 1: a hard edge");
    ImGui::SameLine();
    ImGui::SetNextItemWidth(120);
    ImGui::SliderFloat("opacity", &m_brush.opacity, 0.0f, 1.0f, "%.2f");
    item_tooltip("The most a stroke covers; strokes build up");
    int mode = m_brush.mode;
    ImGui::RadioButton("Paint", &mode, Brush::Paint);
    item_tooltip("Paint the colour over the fitted atlas");
    ImGui::SameLine();
    ImGui::RadioButton("Erase", &mode, Brush::Erase);
    item_tooltip("Remove edits: the fitted atlas shows again");
    ImGui::SameLine();
    ImGui::RadioButton("Clone", &mode, Brush::Clone);
    item_tooltip("Copy the atlas from an offset source (Alt+click sets it)");
    m_brush.mode = Brush::Mode(mode);
    if (m_brush.mode == Brush::Clone) {
        ImGui::SameLine();
        ImGui::TextDisabled(m_have_clone_src ? "(Alt+click: new source)"
                                             : "Alt+click to set the source");
    }
    ImGui::SameLine(0, 24);
    ImGui::BeginDisabled(!ed.can_undo());
    if (ImGui::Button("Undo")) ed.undo();
    item_tooltip("Undo the last stroke or import (Ctrl+Z)");
    ImGui::EndDisabled();
    ImGui::SameLine();
    ImGui::BeginDisabled(!ed.can_redo());
    if (ImGui::Button("Redo")) ed.redo();
    item_tooltip("Redo (Ctrl+Shift+Z)");
    ImGui::EndDisabled();
    ImGui::SameLine();
    ImGui::SetNextItemWidth(100);
    ImGui::SliderFloat("zoom", &m_zoom, 0.1f, 32.0f, "%.2fx", ImGuiSliderFlags_Logarithmic);
    item_tooltip("Atlas zoom (mouse wheel); right or middle drag pans");
    ImGui::SameLine();
    if (ImGui::Button("Fit")) m_zoom = 1.0f, m_pan[0] = m_pan[1] = 0;
    item_tooltip("Fit the atlas to the panel");

    draw_file_buttons();
    ImGui::Text("%dx%d  %s", ed.width(), ed.height(), ed.has_edits() ? "edited" : "no edits");
    if (!m_status.empty() && m_error.empty()) {
        ImGui::SameLine();
        ImGui::TextDisabled("%s", m_status.c_str());
    }
    if (!m_error.empty()) {
        ImGui::SameLine();
        ImGui::TextColored(ImVec4(1.0f, 0.4f, 0.35f, 1.0f), "%s", m_error.c_str());
    }
}

// Export and import ask for the file through the browser; the layer shown is the one written.
void AtlasPanel::ask_export(const std::string& dir) {
    BrowseOptions o;
    o.mode = BrowseMode::Save;
    o.filter = BrowseFilter::Images;
    o.title = "Export the atlas";
    o.ok = "Export";
    o.dir = dir;
    o.name =
        std::string("atlas_") + (m_layer ? "fg" : "bg") + "_edit" + kExportExts[m_export_format];
    m_browser.open(o);
    m_browsing = Browsing::Export;
}

void AtlasPanel::ask_import(const std::string& dir) {
    BrowseOptions o;
    o.filter = BrowseFilter::Images;
    o.title = "Import an atlas image";
    o.ok = "Import";
    o.dir = dir;
    m_browser.open(o);
    m_browsing = Browsing::Import;
}

void AtlasPanel::draw_file_buttons() {
    if (ImGui::Button("Export...")) ask_export();
    item_tooltip("Write this layer's edited atlas to an image file (asks where)");
    ImGui::SameLine();
    ImGui::SetNextItemWidth(90);
    ImGui::Combo("##fmt", &m_export_format, kExportNames, 3);
    item_tooltip("The exported file's format; a name ending in .png, .tif or .exr picks it too");
    ImGui::SameLine();
    if (ImGui::Button("Import...")) ask_import();
    item_tooltip(
        "Read a repainted export (the atlas's size): where it differs from the\n"
        "fitted atlas becomes the edit, one step that Undo takes back");
    if (m_project) {
        ImGui::SameLine(0, 24);
        if (ImGui::Button("Save edits")) guarded([&] { m_edits->save(*m_project); });
        item_tooltip("Write the edits into the project (edits/, project.json)");
    }
}

void AtlasPanel::take_browser_pick() {
    if (m_browser.draw() != BrowseEvent::Picked) return;
    fs::path p = m_browser.picked();
    if (m_browsing == Browsing::Export) {
        const int f = format_of_name(p);
        if (f >= 0)
            m_export_format = f;
        else
            p += kExportExts[m_export_format];
        if (export_atlas(m_layer, p.string(), kExportFormats[m_export_format]))
            m_status = "wrote " + p.string();
    } else if (m_browsing == Browsing::Import && import_atlas(m_layer, p.string())) {
        m_status = "imported " + p.string();
    }
    m_browsing = Browsing::None;
}

void AtlasPanel::draw_canvas(AtlasEditor& ed) {
    ImGuiIO& io = ImGui::GetIO();
    const ImVec2 avail = ImGui::GetContentRegionAvail();
    const ImVec2 p0 = ImGui::GetCursorScreenPos();
    const ImVec2 size(std::max(avail.x, 32.0f), std::max(avail.y, 32.0f));
    ImGui::InvisibleButton("canvas", size,
                           ImGuiButtonFlags_MouseButtonLeft | ImGuiButtonFlags_MouseButtonMiddle |
                               ImGuiButtonFlags_MouseButtonRight);
    const bool hovered = ImGui::IsItemHovered(), active = ImGui::IsItemActive();
    upload(m_layer);

    // Atlas px → screen: origin + p · scale (scale = fit-in-canvas · zoom).
    const float fit = std::min(size.x / ed.width(), size.y / ed.height());
    float scale = fit * m_zoom;
    auto origin = [&] {
        return ImVec2(p0.x + 0.5f * (size.x - ed.width() * scale) + m_pan[0],
                      p0.y + 0.5f * (size.y - ed.height() * scale) + m_pan[1]);
    };
    if (hovered && io.MouseWheel != 0.0f) {  // zoom about the cursor
        const ImVec2 o = origin();
        const float ax = (io.MousePos.x - o.x) / scale, ay = (io.MousePos.y - o.y) / scale;
        m_zoom = std::clamp(m_zoom * std::pow(1.2f, io.MouseWheel), 0.1f, 32.0f);
        scale = fit * m_zoom;
        const ImVec2 o2 = origin();
        m_pan[0] += io.MousePos.x - (o2.x + ax * scale);
        m_pan[1] += io.MousePos.y - (o2.y + ay * scale);
    }
    if (active && (ImGui::IsMouseDragging(ImGuiMouseButton_Middle, 0) ||
                   ImGui::IsMouseDragging(ImGuiMouseButton_Right, 0)))
        m_pan[0] += io.MouseDelta.x, m_pan[1] += io.MouseDelta.y;
    const ImVec2 o = origin();
    m_origin[0] = o.x, m_origin[1] = o.y, m_scale = scale;
    const float ax = (io.MousePos.x - o.x) / scale, ay = (io.MousePos.y - o.y) / scale;

    ImDrawList* dl = ImGui::GetWindowDrawList();
    dl->PushClipRect(p0, ImVec2(p0.x + size.x, p0.y + size.y), true);
    dl->AddRectFilled(p0, ImVec2(p0.x + size.x, p0.y + size.y), IM_COL32(30, 30, 34, 255));
    dl->AddImage(reinterpret_cast<ImTextureID>(static_cast<intptr_t>(m_tex[m_layer])), o,
                 ImVec2(o.x + ed.width() * scale, o.y + ed.height() * scale));

    // Left button: pick, set the clone source (Alt), or paint.
    if (hovered && ImGui::IsMouseClicked(ImGuiMouseButton_Left)) {
        if (m_picking) {
            auto c = ed.pick(ax, ay);
            std::copy(c.begin(), c.end(), m_brush.color);
            m_picking = false;
        } else if (io.KeyAlt && m_brush.mode == Brush::Clone) {
            m_clone_src[0] = ax, m_clone_src[1] = ay;
            m_have_clone_src = true, m_clone_aligned = false;
        } else if (m_brush.mode != Brush::Clone || m_have_clone_src) {
            if (m_brush.mode == Brush::Clone && !m_clone_aligned) {  // aligned: offset kept
                m_brush.clone_dx = m_clone_src[0] - ax, m_brush.clone_dy = m_clone_src[1] - ay;
                m_clone_aligned = true;
            }
            m_painting = guarded([&] {
                ed.begin_stroke(m_brush);
                ed.dab(ax, ay);
            });
        }
    } else if (m_painting && ImGui::IsMouseDown(ImGuiMouseButton_Left)) {
        if (io.MouseDelta.x != 0.0f || io.MouseDelta.y != 0.0f) ed.stroke_to(ax, ay);
    } else if (m_painting) {
        ed.end_stroke();
        m_painting = false;
    }

    if (hovered) {  // brush outline, clone source
        const float r = 0.5f * m_brush.size * scale;
        dl->AddCircle(io.MousePos, std::max(r, 2.0f), IM_COL32(255, 255, 255, 200), 0, 1.5f);
        dl->AddCircle(io.MousePos, std::max(r, 2.0f) + 1.0f, IM_COL32(0, 0, 0, 160));
        ImGui::SetTooltip("%.0f, %.0f", std::floor(ax), std::floor(ay));
    }
    if (m_brush.mode == Brush::Clone && m_have_clone_src) {
        const float sx = m_clone_aligned
                             ? (m_painting || hovered ? ax + m_brush.clone_dx : m_clone_src[0])
                             : m_clone_src[0];
        const float sy = m_clone_aligned
                             ? (m_painting || hovered ? ay + m_brush.clone_dy : m_clone_src[1])
                             : m_clone_src[1];
        const ImVec2 c(o.x + sx * scale, o.y + sy * scale);
        dl->AddLine(ImVec2(c.x - 6, c.y), ImVec2(c.x + 6, c.y), IM_COL32(255, 220, 0, 255), 1.5f);
        dl->AddLine(ImVec2(c.x, c.y - 6), ImVec2(c.x, c.y + 6), IM_COL32(255, 220, 0, 255), 1.5f);
    }
    dl->PopClipRect();
}

bool AtlasPanel::draw(bool* open) {
    if (ImGui::Begin("Atlas", open)) {
        if (!m_edits) {
            ImGui::TextWrapped("No project edits: open a fitted project.");
        } else if (ImGui::BeginTabBar("layers")) {
            for (int i = 0; i < 2; ++i) {
                if (!ImGui::BeginTabItem(kLayerLabel[i])) continue;
                if (m_layer != i && m_painting)
                    m_edits->layer(m_layer).end_stroke(), m_painting = false;
                m_layer = i;
                AtlasEditor& ed = m_edits->layer(i);
                if (ed.base().empty()) {
                    ImGui::TextWrapped(i == 0 ? "No fitted atlas yet."
                                              : "No foreground atlas (the fit has one layer).");
                } else {
                    const bool focused =
                        ImGui::IsWindowFocused(ImGuiFocusedFlags_RootAndChildWindows);
                    const ImGuiIO& io = ImGui::GetIO();
                    if (focused && !io.WantTextInput) {
                        if (io.KeyCtrl && ImGui::IsKeyPressed(ImGui::GetKeyIndex(ImGuiKey_Z)))
                            io.KeyShift ? ed.redo() : ed.undo();
                        if (io.KeyCtrl && ImGui::IsKeyPressed(ImGui::GetKeyIndex(ImGuiKey_Y)))
                            ed.redo();
                        if (!io.KeyCtrl && ImGui::IsKeyPressed('I'))
                            m_picking = !m_picking;  // GLFW_KEY_I
                    }
                    draw_controls(ed);
                    draw_canvas(ed);
                }
                ImGui::EndTabItem();
            }
            ImGui::EndTabBar();
        }
    }
    take_browser_pick();
    ImGui::End();
    bool changed = false;
    for (int i = 0; m_edits && i < 2; ++i) {
        const int64_t v = m_edits->layer(i).version();
        changed |= m_reported[i] != v;
        m_reported[i] = v;
    }
    return changed;
}

}  // namespace refocus
