#pragma once
// The studio's background thread: it owns the project's FitEngine, runs the fit step by step,
// and renders what the UI asks for (a frame's layers, the atlases, the depth
// model) between two steps, so the UI thread never waits on LibTorch. The UI posts requests and
// picks up results from mailboxes; nothing here touches GL or ImGui.
#include <condition_variable>
#include <deque>
#include <functional>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "edit/depth.h"
#include "edit/recompose.h"
#include "session/fit_session.h"

namespace refocus {

class FitWorker {
  public:
    enum class State { Empty, Preparing, Unfitted, Ready, Fitting, Paused, Failed };

    struct Status {
        State state = State::Empty;
        FitSnapshot snap;
        std::vector<FitSnapshot> history;  // one entry per step (thinned when long)
        std::vector<std::string> log;
        std::string error;  // last error (kept up to the next request)
        bool busy = false;  // a job is running (prepare, render, export)
        std::string busy_what;
        double job_progress = 0.0;  // 0..1 of the running job when it reports one
        // While Preparing: the step the preparation is at (engine/prepare/log.h stages), how
        // long it has run and an estimate from the steps' shares; the last one's duration.
        struct Preparation {
            std::string stage;  // empty until the first step is reported
            double elapsed_s = 0.0;
            double eta_s = -1.0;    // -1 while unknown
            double progress = 0.0;  // 0..1
        } prep;
        double prep_s = 0.0;  // the last fit's preparation, counted in its time budget
    };

    FitWorker();
    ~FitWorker();  // stops a running fit (checkpointing it) and joins
    FitWorker(const FitWorker&) = delete;
    FitWorker& operator=(const FitWorker&) = delete;

    // Opens `project`: prepares its data and loads its last checkpoint when there is one.
    void open(const Project& project);
    void close();
    // Starts (or, with `resume` and a checkpoint, continues) a fit with these settings. The
    // settings are written into project.json's "fit" section.
    void start(const FitSettings& settings, bool resume);
    void set_paused(bool paused);
    void stop();  // the fit stops after its current step and is checkpointed

    // Rendering, answered on the worker thread; the newest answer waits in a mailbox.
    struct ViewFrame {
        int t = 0;
        FrameMaps maps;
        Image radius;  // 1 channel, px: the radius the fit uses at this frame
        // 2 channels: the confidence that the fit explains the pixel, and the fit's share of
        // the sharp plate there (FitEngine::confidence, model_weight).
        Image confidence;
        int64_t atlas_version = 0;
    };
    // Frame t is rendered before the next fit step; the future holds nothing when no fit is open
    // or the worker closes first. The viewer's renderer waits on it off the UI thread.
    std::future<std::optional<ViewFrame>> frame_async(int t);
    void request_atlases();
    struct Atlases {
        Image bg, fg;
        int64_t version = 0;
    };
    std::optional<Atlases> take_atlases();
    // Depth model: loaded from <project>/depth/ when it matches the checkpoint, else fitted and
    // saved there.
    void request_depth(bool rebuild = false);
    std::shared_ptr<const DepthModel> depth() const;

    // Runs `job` on the worker thread with the engine (nullptr when none is open). `progress`
    // may be called from the job; `cancelled()` is true after cancel_job().
    using Job = std::function<void(FitEngine* engine, const Project& project)>;
    void post(const std::string& what, Job job);
    void cancel_job() { m_cancel = true; }
    bool cancelled() const { return m_cancel; }
    void set_job_progress(double p);
    // A job's one-line outcome, for the UI to pick up (export results).
    void post_result(const std::string& r);
    std::optional<std::string> take_result();

    // The state; with `full`, also the step history and the log (copies: ask only to draw them).
    Status status(bool full = false) const;
    bool has_engine() const;
    bool has_checkpoint() const;
    FitSettings settings() const;
    std::string project_dir() const;

  private:
    void loop();
    void run_job(const std::string& what, const Job& job);
    void add_log(const std::string& line);
    void set_state(State s);
    void fit_step();
    void end_fit(const std::string& why);
    std::optional<ViewFrame> render_view_frame(int t);
    // Preparation progress, reported from the worker thread through PrepareLog's stage sink.
    void begin_prep();
    void prep_stage(const std::string& name, double begin, double end);
    double prep_elapsed() const;

    std::thread m_thread;
    mutable std::mutex m_mutex;  // guards everything below except the engine
    std::condition_variable m_cv;
    std::deque<std::pair<std::string, Job>> m_jobs;
    bool m_quit = false;
    bool m_fitting = false;
    std::atomic<bool> m_cancel{false};
    Status m_status;

    // Owned by the worker thread (set through jobs).
    std::unique_ptr<Project> m_project;
    std::unique_ptr<FitEngine> m_engine;
    FitSettings m_settings;
    bool m_has_checkpoint = false;

    std::deque<std::pair<int, std::promise<std::optional<ViewFrame>>>> m_frame_jobs;
    bool m_atlas_request = false;
    std::optional<Atlases> m_atlas_result;
    std::optional<std::string> m_result;
    std::shared_ptr<const DepthModel> m_depth;
    int64_t m_depth_step = -1;

    // Guarded by m_mutex: when the preparation and its current step began (steady clock, s),
    // the step's share of the work, the estimated total, the progress last shown.
    double m_prep_t0 = 0.0, m_step_t0 = 0.0, m_step_begin = 0.0, m_step_end = 0.0;
    double m_prep_total_s = -1.0;
    mutable double m_prep_shown = 0.0;
};

const char* state_name(FitWorker::State s);

}  // namespace refocus
