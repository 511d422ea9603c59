// Refocus Studio: the window, the viewer with scrub and play, File > Open.
#include "studio.h"

#include <GLFW/glfw3.h>
#include <GL/gl.h>
#include <imgui.h>
#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl3.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdio>
#include <memory>

#include "frame_source.h"
#include "io/image_file.h"
#include "util/error.h"
#include "util/fs.h"

namespace refocus {

namespace {

struct ViewerState {
    std::unique_ptr<FrameSource> source;
    int frame = 0;
    int shown_frame = -1;
    bool playing = false;
    double play_clock = 0.0;
    GLuint texture = 0;
    float zoom = 0.0f;  // 0: fit to window
    // Where the image was drawn last frame, in framebuffer pixels (for screenshots / tests).
    float img_x = 0, img_y = 0, img_w = 0, img_h = 0;
    std::string error;
    char open_buf[1024] = {0};
};

void upload_frame(ViewerState& v) {
    if (!v.source || v.shown_frame == v.frame) return;
    const auto& px = v.source->rgba8(v.frame);
    if (!v.texture) glGenTextures(1, &v.texture);
    glBindTexture(GL_TEXTURE_2D, v.texture);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, v.source->width(), v.source->height(), 0, GL_RGBA,
                 GL_UNSIGNED_BYTE, px.data());
    v.shown_frame = v.frame;
}

void open_source(ViewerState& v, const std::string& path) {
    try {
        auto src = std::make_unique<FrameSource>(path);
        v.source = std::move(src);
        v.frame = 0;
        v.shown_frame = -1;
        v.playing = false;
        v.error.clear();
    } catch (const std::exception& e) {
        v.error = e.what();
    }
}

void draw_viewer(ViewerState& v, float fb_scale) {
    const ImGuiViewport* vp = ImGui::GetMainViewport();
    ImGui::SetNextWindowPos(vp->WorkPos);
    ImGui::SetNextWindowSize(vp->WorkSize);
    ImGui::Begin("Viewer", nullptr,
                 ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_NoMove |
                     ImGuiWindowFlags_NoBringToFrontOnFocus | ImGuiWindowFlags_NoSavedSettings);
    if (!v.source) {
        ImGui::TextWrapped("No clip open. Use File > Open, or start refocus-studio <project-or-clip>.");
    } else {
        FrameSource& s = *v.source;
        ImGui::Text("%s   %dx%d   %d frames   %.2f fps", s.label().c_str(), s.width(), s.height(),
                    s.frames(), s.fps());
        const float controls_h = ImGui::GetFrameHeightWithSpacing() * 2.0f;
        ImVec2 avail = ImGui::GetContentRegionAvail();
        avail.y -= controls_h;
        float scale = v.zoom > 0 ? v.zoom
                                 : std::min(avail.x / s.width(), std::max(avail.y, 1.0f) / s.height());
        ImVec2 size(s.width() * scale, s.height() * scale);
        ImGui::BeginChild("image", ImVec2(avail.x, avail.y), false,
                          ImGuiWindowFlags_HorizontalScrollbar);
        ImVec2 cursor = ImGui::GetCursorScreenPos();
        ImVec2 region = ImGui::GetContentRegionAvail();
        ImVec2 offset(std::max(0.0f, (region.x - size.x) * 0.5f),
                      std::max(0.0f, (region.y - size.y) * 0.5f));
        ImGui::SetCursorScreenPos(ImVec2(cursor.x + offset.x, cursor.y + offset.y));
        upload_frame(v);
        ImVec2 pos = ImGui::GetCursorScreenPos();
        ImGui::Image(reinterpret_cast<ImTextureID>(static_cast<intptr_t>(v.texture)), size);
        v.img_x = pos.x * fb_scale;
        v.img_y = pos.y * fb_scale;
        v.img_w = size.x * fb_scale;
        v.img_h = size.y * fb_scale;
        ImGui::EndChild();

        if (ImGui::Button(v.playing ? "Pause" : "Play") ||
            (ImGui::IsKeyPressed(ImGui::GetKeyIndex(ImGuiKey_Space)) && !ImGui::GetIO().WantTextInput)) {
            v.playing = !v.playing;
            v.play_clock = glfwGetTime();
        }
        ImGui::SameLine();
        if (ImGui::Button("<")) v.frame = std::max(0, v.frame - 1);
        ImGui::SameLine();
        if (ImGui::Button(">")) v.frame = std::min(s.frames() - 1, v.frame + 1);
        ImGui::SameLine();
        ImGui::SetNextItemWidth(-1);
        ImGui::SliderInt("##frame", &v.frame, 0, s.frames() - 1, "frame %d");
        ImGui::SetNextItemWidth(160);
        ImGui::SliderFloat("zoom (0 = fit)", &v.zoom, 0.0f, 8.0f, "%.2f");
        if (v.playing) {
            double now = glfwGetTime();
            int steps = static_cast<int>((now - v.play_clock) * s.fps());
            if (steps > 0) {
                v.frame = (v.frame + steps) % s.frames();
                v.play_clock += steps / s.fps();
            }
        }
    }
    ImGui::End();
}

void write_screenshot(const std::string& path, int w, int h, const ViewerState& v) {
    std::vector<unsigned char> px(static_cast<size_t>(w) * h * 4);
    glPixelStorei(GL_PACK_ALIGNMENT, 1);
    glReadPixels(0, 0, w, h, GL_RGBA, GL_UNSIGNED_BYTE, px.data());
    Image img(w, h, 3);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
            for (int c = 0; c < 3; ++c)
                img.at(x, y, c) = px[(static_cast<size_t>(h - 1 - y) * w + x) * 4 + c] / 255.0f;
    write_image_file(path, img, PixelFormat::Png8, false);
    nlohmann::json meta = {{"window", {w, h}},
                           {"frame", v.frame},
                           {"image_rect", {v.img_x, v.img_y, v.img_w, v.img_h}}};
    write_file_atomic(path + ".json", meta.dump(2));
}

}  // namespace

int run_studio(const StudioOptions& opts) {
    glfwSetErrorCallback([](int code, const char* msg) {
        std::fprintf(stderr, "refocus-studio: GLFW error %d: %s\n", code, msg);
    });
    if (!glfwInit()) throw Error("cannot initialise GLFW (no display? run under Xvfb)");
    glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 3);
    glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 3);
    glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
    GLFWwindow* window = glfwCreateWindow(opts.width, opts.height, "Refocus Studio", nullptr, nullptr);
    if (!window) {
        glfwTerminate();
        throw Error("cannot create an OpenGL 3.3 window");
    }
    glfwMakeContextCurrent(window);
    glfwSwapInterval(1);

    IMGUI_CHECKVERSION();
    ImGui::CreateContext();
    ImGui::GetIO().IniFilename = nullptr;
    ImGui::StyleColorsDark();
    ImGui_ImplGlfw_InitForOpenGL(window, true);
    ImGui_ImplOpenGL3_Init("#version 330 core");

    ViewerState v;
    if (!opts.open_path.empty()) {
        open_source(v, opts.open_path);
        if (!v.error.empty() && opts.exit_after >= 0) {
            std::fprintf(stderr, "refocus-studio: error: %s\n", v.error.c_str());
            return 1;
        }
        if (v.source) v.frame = std::clamp(opts.start_frame, 0, v.source->frames() - 1);
    }

    int rendered = 0;
    bool show_open = false;
    while (!glfwWindowShouldClose(window)) {
        if (glfwGetWindowAttrib(window, GLFW_ICONIFIED)) {
            glfwWaitEventsTimeout(0.1);  // minimised: sleep instead of drawing
            continue;
        }
        glfwPollEvents();
        ImGui_ImplOpenGL3_NewFrame();
        ImGui_ImplGlfw_NewFrame();
        ImGui::NewFrame();

        if (ImGui::BeginMainMenuBar()) {
            if (ImGui::BeginMenu("File")) {
                if (ImGui::MenuItem("Open...", "Ctrl+O")) show_open = true;
                if (ImGui::MenuItem("Quit", "Ctrl+Q")) glfwSetWindowShouldClose(window, 1);
                ImGui::EndMenu();
            }
            ImGui::EndMainMenuBar();
        }
        int fbw, fbh, ww, wh;
        glfwGetFramebufferSize(window, &fbw, &fbh);
        glfwGetWindowSize(window, &ww, &wh);
        draw_viewer(v, ww > 0 ? float(fbw) / ww : 1.0f);

        if (show_open) {
            ImGui::OpenPopup("Open");
            show_open = false;
        }
        if (ImGui::BeginPopupModal("Open", nullptr, ImGuiWindowFlags_AlwaysAutoResize)) {
            ImGui::Text("Project folder, video file or image sequence (folder or pattern):");
            ImGui::SetNextItemWidth(500);
            bool go = ImGui::InputText("##path", v.open_buf, sizeof v.open_buf,
                                       ImGuiInputTextFlags_EnterReturnsTrue);
            if (ImGui::Button("Open") || go) {
                open_source(v, v.open_buf);
                ImGui::CloseCurrentPopup();
            }
            ImGui::SameLine();
            if (ImGui::Button("Cancel")) ImGui::CloseCurrentPopup();
            ImGui::EndPopup();
        }
        if (!v.error.empty()) ImGui::OpenPopup("Error");
        if (ImGui::BeginPopupModal("Error", nullptr, ImGuiWindowFlags_AlwaysAutoResize)) {
            ImGui::TextWrapped("%s", v.error.c_str());
            if (ImGui::Button("OK")) {
                v.error.clear();
                ImGui::CloseCurrentPopup();
            }
            ImGui::EndPopup();
        }

        ImGui::Render();
        glViewport(0, 0, fbw, fbh);
        glClearColor(0.08f, 0.08f, 0.09f, 1.0f);
        glClear(GL_COLOR_BUFFER_BIT);
        ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
        ++rendered;
        if (opts.exit_after >= 0 && rendered >= opts.exit_after) {
            if (!opts.screenshot.empty()) write_screenshot(opts.screenshot, fbw, fbh, v);
            glfwSetWindowShouldClose(window, 1);
        }
        glfwSwapBuffers(window);
    }

    if (v.texture) glDeleteTextures(1, &v.texture);
    ImGui_ImplOpenGL3_Shutdown();
    ImGui_ImplGlfw_Shutdown();
    ImGui::DestroyContext();
    glfwDestroyWindow(window);
    glfwTerminate();
    return 0;
}

}  // namespace refocus
